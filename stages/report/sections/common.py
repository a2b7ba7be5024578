"""What several sections share: the section's signature, the page's record, numbers as the
page shows them, and the held-out image scores."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from endopipe.stages.report.load import CaseData


@dataclass
class ReportInfo:
    """What the page ended up holding (the report stage's summary)."""

    gt_kind: str = "none"
    mesh_viewer: str = "none"
    sections: dict[str, bool] = field(default_factory=dict)


#: A section: the case in, its HTML out (None when it has nothing at all to show).
Section = Callable[[CaseData, ReportInfo], "str | None"]


@dataclass(frozen=True)
class Figure:
    """An image on the page: its data URI and caption."""

    uri: str
    caption: str


def number(value: Any) -> float | None:
    """A JSON value as a float, None when it is not a number (bools are not numbers)."""
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    return float(value) if ok else None


def heldout_image_scores(data: CaseData) -> tuple[float | None, float | None]:
    """PSNR and SSIM of the held-out frames: the depth stage's, else the NeRF stage's PSNR
    (the NeRF stage measures no SSIM)."""
    dm, nm = data.depth_metrics, data.nerf_metrics
    psnr = number(dm.heldout_psnr) if dm is not None else None
    ssim = number(dm.heldout_ssim) if dm is not None else None
    if psnr is None and nm is not None:
        psnr = number(nm.psnr)
    return psnr, ssim
