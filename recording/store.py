"""Writing `<case>/recording/`: its cache key and its atomic publish, both the engine's own
(`pipeline.cache`: a chained key over canonical JSON, `manifest.json` written last, the folder
renamed into place), so a recording is cached, checked and resumed as a stage's folder is."""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Any

from endopipe.pipeline.cache import (
    Manifest,
    list_files,
    publish,
    stage_key,
    stale_temps,
    temp_dir_for,
)
from endopipe.pipeline.runner import Pipeline
from endopipe.pipeline.stage import CaseInfo, StageConfig, write_json
from endopipe.recording.join import Joined
from endopipe.recording.options import RecordingOptions
from endopipe.recording.paths import (
    SUMMARY_FILE,
    TRAJECTORY_FILE,
    WINDOWS_FILE,
)
from endopipe.recording.summary import RecordingSummary
from endopipe.recording.view import RecordingView
from endopipe.recording.windows import WindowPlan

NAME = "recording"
#: Bumped when what the recording writes from the same windows changes meaning.
VERSION = 6


class RecordingInputs:
    """What recording/ is made from, as the engine keys a stage: the settings it reads (the cut,
    the light's scale, how far the run goes, the depth and mesh settings) and its upstream (the
    recording's ingest and every window stage's own cache key)."""

    def __init__(
        self,
        pipe: Pipeline,
        case_dir: Path,
        plan: WindowPlan,
        configs: dict[str, StageConfig],
        options: RecordingOptions,
        until: str | None,
    ) -> None:
        view = RecordingView(case_dir)
        ingest = pipe.manifest(case_dir, "ingest")
        self.config: dict[str, Any] = {
            "windows": plan.windows,
            "light_scale": options.light_scale,
            "until": until,
            "depth": configs["depth"].model_dump(mode="json"),
            "mesh": configs["mesh"].model_dump(mode="json"),
        }
        self.upstream: dict[str, str] = {"ingest": ingest.key if ingest else ""}
        for name in plan.names():
            keys = [
                m.key if (m := pipe.manifest(view.windows_dir / name, s.name)) else ""
                for s in pipe.selection(until)
            ]
            self.upstream[name] = ",".join(keys)
        self.input_digest = CaseInfo.load(case_dir).input_digest

    @property
    def key(self) -> str:
        return stage_key(NAME, VERSION, self.config, self.upstream, self.input_digest)


class Staging:
    """recording/ being written: a temporary folder named after the key (the engine's naming),
    sealed with its manifest and renamed into place, or left for the next run to remove."""

    def __init__(self, case_dir: Path, inputs: RecordingInputs) -> None:
        self.inputs = inputs
        self.key = inputs.key
        self.final = RecordingView(case_dir).folder
        self.dir = temp_dir_for(self.final, self.key)
        for stale in stale_temps(self.final, keep=None):
            shutil.rmtree(stale, ignore_errors=True)
        self.dir.mkdir(parents=True)
        self.started = time.time()
        self._t0 = time.perf_counter()

    def publish(
        self, plan: WindowPlan, joined: Joined, summary: RecordingSummary, peak_rss_mb: float
    ) -> None:
        """The cut, the trajectory and the summary written, then the folder sealed and swapped
        into place: a reader sees the previous recording/ or this one, never half of one."""
        write_json(self.dir / WINDOWS_FILE, plan.model_dump(mode="json"))
        write_json(self.dir / TRAJECTORY_FILE, joined.model_dump(mode="json"))
        write_json(self.dir / SUMMARY_FILE, summary.model_dump(mode="json"))
        manifest = Manifest(
            stage=NAME,
            key=self.key,
            version=VERSION,
            config=self.inputs.config,
            upstream=self.inputs.upstream,
            started=self.started,
            finished=time.time(),
            wall_s=time.perf_counter() - self._t0,
            peak_rss_mb=peak_rss_mb,
            summary=summary.model_dump(mode="json"),
            files=list_files(self.dir),
        )
        publish(self.dir, self.final, manifest)
