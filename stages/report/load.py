"""What the report shows, gathered once and only through the stages' views and the engine.

Each stage folder is opened with its stage's view (the one reader of that folder), and its
summary is read back as the stage's own model (`view.summary`); manifests and run records come
from the engine. Anything missing or unreadable becomes None with the reason kept, so a section
can say "not available" instead of taking the page down; a summary that does not validate is
remembered with its reason, and the page marks every section that asked for it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from endopipe.pipeline.cache import Manifest
from endopipe.pipeline.errors import SummaryMismatch
from endopipe.pipeline.runner import RunRecord, read_runs
from endopipe.pipeline.stage import CaseInfo, Stage, Summary
from endopipe.stages.report.config import ReportConfig
from endopipe.stages.report.kit import one_line

if TYPE_CHECKING:
    from endopipe.stages.centerline.summary import CenterlineSummary
    from endopipe.stages.centerline.view import CenterlineView
    from endopipe.stages.depth.metrics_file import DepthMetrics
    from endopipe.stages.depth.summary import DepthSummary
    from endopipe.stages.depth.view import DepthView
    from endopipe.stages.ingest.summary import IngestSummary
    from endopipe.stages.ingest.view import IngestView
    from endopipe.stages.io.ground_truth import GroundTruthSource
    from endopipe.stages.mesh.metrics_file import MeshMetrics
    from endopipe.stages.mesh.summary import MeshSummary
    from endopipe.stages.mesh.view import MeshView
    from endopipe.stages.nerf.metrics_file import NerfMetrics
    from endopipe.stages.nerf.summary import NerfSummary
    from endopipe.stages.nerf.view import NerfView
    from endopipe.stages.poses.summary import PosesSummary
    from endopipe.stages.poses.verdict import PoseVerdict
    from endopipe.stages.poses.view import PosesView

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
    """The artefacts of one case, loaded once: views and typed summaries (None when absent),
    manifests, runs."""

    case_dir: Path
    folders: dict[str, Path]
    cfg: ReportConfig
    case: CaseInfo | None = None
    views: dict[str, Any] = field(default_factory=dict)
    view_errors: dict[str, str] = field(default_factory=dict)
    summaries: dict[str, Summary] = field(default_factory=dict)
    #: stage -> why its summary could not be read (e.g. it does not match the stage's model)
    summary_errors: dict[str, str] = field(default_factory=dict)
    #: the stages whose summaries were asked for since `summaries_read` was last cleared: the
    #: page marks a section that asked for an unreadable one as not available
    summaries_read: set[str] = field(default_factory=set)
    manifests: dict[str, Manifest | None] = field(default_factory=dict)
    runs: list[RunRecord] = field(default_factory=list)
    _gt: Any = None
    _gt_error: str | None = None
    _verdict: Any = None
    verdict_error: str | None = None
    _metrics: dict[str, Any] = field(default_factory=dict)

    # --- views, as each stage's own class (None when its folder is absent or unreadable) -----
    def _view(self, stage: str) -> Any:
        return self.views[stage] if stage in self.views else None

    @property
    def ingest(self) -> IngestView | None:
        return cast("IngestView | None", self._view("ingest"))

    @property
    def poses(self) -> PosesView | None:
        return cast("PosesView | None", self._view("poses"))

    @property
    def centerline(self) -> CenterlineView | None:
        return cast("CenterlineView | None", self._view("centerline"))

    @property
    def nerf(self) -> NerfView | None:
        return cast("NerfView | None", self._view("nerf"))

    @property
    def depth(self) -> DepthView | None:
        return cast("DepthView | None", self._view("depth"))

    @property
    def mesh(self) -> MeshView | None:
        return cast("MeshView | None", self._view("mesh"))

    def folder(self, stage: str) -> Path | None:
        """The stage's published folder, when it exists (its name is shown, never parsed)."""
        path = self.folders.get(stage)
        return path if path is not None and path.is_dir() else None

    # --- summaries, as each stage's own model ---------------------------------------------------
    def summary(self, stage: str) -> Summary | None:
        """The stage's summary (None when its folder is absent or the summary unreadable; the
        reason is in `summary_errors`)."""
        self.summaries_read.add(stage)
        return self.summaries.get(stage)

    @property
    def ingest_summary(self) -> IngestSummary | None:
        return cast("IngestSummary | None", self.summary("ingest"))

    @property
    def poses_summary(self) -> PosesSummary | None:
        return cast("PosesSummary | None", self.summary("poses"))

    @property
    def centerline_summary(self) -> CenterlineSummary | None:
        return cast("CenterlineSummary | None", self.summary("centerline"))

    @property
    def nerf_summary(self) -> NerfSummary | None:
        return cast("NerfSummary | None", self.summary("nerf"))

    @property
    def depth_summary(self) -> DepthSummary | None:
        return cast("DepthSummary | None", self.summary("depth"))

    @property
    def mesh_summary(self) -> MeshSummary | None:
        return cast("MeshSummary | None", self.summary("mesh"))

    # --- metrics files, as the views give them ---------------------------------------------------
    @property
    def depth_metrics(self) -> DepthMetrics | None:
        """05_depth/metrics.json (None when absent or unreadable)."""
        return cast("DepthMetrics | None", self._read_metrics("depth"))

    @property
    def mesh_metrics(self) -> MeshMetrics | None:
        """06_mesh/metrics.json (None when absent or unreadable)."""
        return cast("MeshMetrics | None", self._read_metrics("mesh"))

    @property
    def nerf_metrics(self) -> NerfMetrics | None:
        """04_nerf/metrics.json (None when absent or unreadable)."""
        return cast("NerfMetrics | None", self._read_metrics("nerf"))

    def _read_metrics(self, stage: str) -> Any:
        """The stage view's `metrics`, read once; None when absent or unreadable."""
        if stage not in self._metrics:
            try:
                self._metrics[stage] = getattr(self._view(stage), "metrics", None)
            except (OSError, ValueError):
                self._metrics[stage] = None
        return self._metrics[stage]

    def pose_verdict(self) -> PoseVerdict | None:
        """02_poses/verdict.json through the poses view: a PoseVerdict, or None for a folder
        written before the verdict existed, or when unreadable (reason in `verdict_error`)."""
        if self._verdict is None and self.verdict_error is None and self.poses is not None:
            try:
                self._verdict = self.poses.verdict()
            except Exception as e:  # noqa: BLE001 - a broken verdict costs its block only
                self.verdict_error = one_line(e)
        return cast("PoseVerdict | None", self._verdict)

    @property
    def units(self) -> str:
        if self.poses is None:
            return ""
        return "mm" if self.poses.metric else str(self.poses.file.units)

    # --- ground truth, through the one door ----------------------------------------------------
    def gt_dir(self) -> Path | None:
        raw = getattr(self.ingest, "gt_dir", None) or (self.case.gt_dir if self.case else None)
        return Path(raw) if raw else None

    def ground_truth(self) -> GroundTruthSource | None:
        """The case's GroundTruthSource, or None (reason in `_gt_error`)."""
        if self._gt is not None or self._gt_error is not None:
            return cast("GroundTruthSource | None", self._gt)
        gt_dir = self.gt_dir()
        if gt_dir is None:
            self._gt_error = "the case has no ground truth"
            return None
        try:
            from endopipe.stages.io.datasets import open_ground_truth

            self._gt = open_ground_truth(gt_dir)
        except Exception as e:  # noqa: BLE001 - any reader failure: report without GT
            self._gt_error = f"ground truth at {gt_dir} could not be read ({one_line(e)})"
        return cast("GroundTruthSource | None", self._gt)

    def gt_kind(self) -> str:
        """exact | pseudo | relative | none: from the evaluations, else from the GT reader."""
        depth, mesh = self.depth_metrics, self.mesh_metrics
        if depth is not None and depth.gt_kind:
            return depth.gt_kind
        if mesh is not None and mesh.gt_kind:
            return mesh.gt_kind
        gt = self.ground_truth()
        return str(getattr(gt, "kind", "exact")) if gt is not None else "none"


def load_case(
    case_dir: Path,
    folders: dict[str, Path],
    cfg: ReportConfig,
    open_view: ViewOpener = stage_view,
) -> CaseData:
    """Open every stage folder in `folders` (name -> published folder) with its view, and read
    its summary through it."""
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
            view = data.views[stage] = open_view(stage, folder)
        except Exception as e:  # noqa: BLE001 - a broken folder costs its sections, not the page
            data.view_errors[stage] = one_line(e)
            continue
        try:
            data.summaries[stage] = view.summary
        except SummaryMismatch as e:  # one line by contract, ending in what to do: kept whole
            data.summary_errors[stage] = str(e)
        except Exception as e:  # noqa: BLE001 - a manifest that cannot be read at all
            data.summary_errors[stage] = f"{stage}'s summary could not be read: {one_line(e)}"

    data.runs = read_runs(data.case_dir, cfg.max_runs) if cfg.max_runs else []
    return data
