"""What the report shows, gathered once and only through the stages' views and the engine.

Each stage folder is opened with its stage's view (the one reader of that folder); manifests
and run records come from the engine. Anything missing or unreadable becomes None with the
reason kept, so a section can say "not available" instead of taking the page down.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from endopipe.pipeline.cache import Manifest
from endopipe.pipeline.runner import RunRecord, read_runs
from endopipe.pipeline.stage import CaseInfo, Stage
from endopipe.stages.report.config import ReportConfig
from endopipe.stages.report.kit import one_line

#: The stages whose folders the report reads, in DAG order.
STAGES = ("ingest", "poses", "centerline", "nerf", "depth", "mesh")

#: Opens a stage's view on its published folder (raises when the folder is unreadable).
ViewOpener = Callable[[str, Path], Any]


def stage_view(name: str, folder: Path) -> Any:
    """The stage's own view of `folder`, as the runner hands it to downstream stages. Each
    stage module is imported only when its folder is read: one broken stage costs its
    sections, not the page."""
    stage: type[Stage]
    if name == "ingest":
        from endopipe.stages.ingest.stage import Ingest as stage
    elif name == "poses":
        from endopipe.stages.poses.stage import Poses as stage
    elif name == "centerline":
        from endopipe.stages.centerline.stage import Centerline as stage
    elif name == "nerf":
        from endopipe.stages.nerf.stage import Nerf as stage
    elif name == "depth":
        from endopipe.stages.depth.stage import Depth as stage
    elif name == "mesh":
        from endopipe.stages.mesh.stage import Mesh as stage
    else:
        raise KeyError(f"the report reads no stage called {name!r}")
    return stage.view(folder)


@dataclass
class CaseData:
    """The artefacts of one case, loaded once: views (None when absent), manifests, runs."""

    case_dir: Path
    folders: dict[str, Path]
    cfg: ReportConfig
    case: CaseInfo | None = None
    views: dict[str, Any] = field(default_factory=dict)
    view_errors: dict[str, str] = field(default_factory=dict)
    manifests: dict[str, Manifest | None] = field(default_factory=dict)
    runs: list[RunRecord] = field(default_factory=list)
    _gt: Any = None
    _gt_error: str | None = None
    _verdict: Any = None
    verdict_error: str | None = None

    # --- views ----------------------------------------------------------------------------------
    @property
    def ingest(self) -> Any:
        return self.views.get("ingest")

    @property
    def poses(self) -> Any:
        return self.views.get("poses")

    @property
    def centerline(self) -> Any:
        return self.views.get("centerline")

    @property
    def nerf(self) -> Any:
        return self.views.get("nerf")

    @property
    def depth(self) -> Any:
        return self.views.get("depth")

    @property
    def mesh(self) -> Any:
        return self.views.get("mesh")

    def folder(self, stage: str) -> Path | None:
        """The stage's published folder, when it exists (its name is shown, never parsed)."""
        path = self.folders.get(stage)
        return path if path is not None and path.is_dir() else None

    def summary(self, stage: str) -> dict:
        m = self.manifests.get(stage)
        return dict(m.summary) if m is not None else {}

    # --- metrics as the stages wrote them ----------------------------------------------------
    @property
    def depth_metrics(self) -> dict | None:
        return self._metrics("depth")

    @property
    def mesh_metrics(self) -> dict | None:
        return self._metrics("mesh")

    @property
    def nerf_metrics(self) -> dict | None:
        return self._metrics("nerf")

    def _metrics(self, stage: str) -> dict | None:
        """The stage view's metrics as a dict; None when absent or unreadable."""
        try:
            return _as_dict(getattr(self.views.get(stage), "metrics", None))
        except (OSError, ValueError):
            return None

    def pose_verdict(self) -> Any:
        """02_poses/verdict.json through the poses view: a PoseVerdict, or None for a folder
        written before the verdict existed, or when unreadable (reason in `verdict_error`)."""
        if self._verdict is None and self.verdict_error is None and self.poses is not None:
            try:
                self._verdict = self.poses.verdict()
            except Exception as e:  # noqa: BLE001 - a broken verdict costs its block only
                self.verdict_error = one_line(e)
        return self._verdict

    @property
    def units(self) -> str:
        if self.poses is None:
            return ""
        return "mm" if self.poses.metric else str(self.poses.file.units)

    # --- ground truth, through the one door ----------------------------------------------------
    def gt_dir(self) -> Path | None:
        raw = getattr(self.ingest, "gt_dir", None) or (self.case.gt_dir if self.case else None)
        return Path(raw) if raw else None

    def ground_truth(self) -> Any:
        """The case's GroundTruthSource, or None (reason in `_gt_error`)."""
        if self._gt is not None or self._gt_error is not None:
            return self._gt
        gt_dir = self.gt_dir()
        if gt_dir is None:
            self._gt_error = "the case has no ground truth"
            return None
        try:
            from endopipe.stages.io.ground_truth import open_ground_truth

            self._gt = open_ground_truth(gt_dir)
        except Exception as e:  # noqa: BLE001 - any reader failure: report without GT
            self._gt_error = f"ground truth at {gt_dir} could not be read ({one_line(e)})"
        return self._gt

    def gt_kind(self) -> str:
        """exact | pseudo | relative | none: from the evaluations, else from the GT reader."""
        for data in (self.depth_metrics, self.mesh_metrics):
            if data and data.get("gt_kind"):
                return str(data["gt_kind"])
        gt = self.ground_truth()
        return str(getattr(gt, "kind", "exact")) if gt is not None else "none"


def load_case(
    case_dir: Path,
    folders: dict[str, Path],
    cfg: ReportConfig,
    open_view: ViewOpener = stage_view,
) -> CaseData:
    """Open every stage folder in `folders` (name -> published folder) with its view."""
    data = CaseData(case_dir=Path(case_dir), folders=dict(folders), cfg=cfg)
    try:
        data.case = CaseInfo.load(data.case_dir)
    except (OSError, ValueError):
        data.case = None
    for stage in STAGES:
        folder = data.folder(stage)
        data.manifests[stage] = Manifest.load(folder) if folder is not None else None
        if folder is None:
            continue
        try:
            data.views[stage] = open_view(stage, folder)
        except Exception as e:  # noqa: BLE001 - a broken folder costs its sections, not the page
            data.view_errors[stage] = one_line(e)
    data.runs = read_runs(data.case_dir, cfg.max_runs) if cfg.max_runs else []
    return data


def _as_dict(value: Any) -> dict | None:
    if value is None:
        return None
    if hasattr(value, "model_dump"):
        return value.model_dump(mode="json", exclude_none=True)
    return dict(value) if isinstance(value, dict) and value else None
