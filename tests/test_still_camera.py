"""A still camera over a wall pulled by a tool, run end to end as a user would (the video and
its intrinsics, no flags): the footage is called what it is, the camera gets one pose, the field
changes with time, and its depth (relative, one viewpoint) still follows the truth better than
the brightness guess."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from endopipe.cli import main
from endopipe.stages.depth import evaluate
from endopipe.stages.depth.view import DepthView
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.mesh.view import MeshView
from endopipe.stages.metrics.depth import depth_frame_metrics
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView
from endopipe.synth import SynthConfig, generate_case

STEPS = ["--set", "nerf.train.steps=400", "--set", "nerf.train.time_budget_s=null"]
STEPS += ["--set", "nerf.train.threads=1", "--set", "report.include_mesh_viewer=false"]
# The bounds below were measured at these 400 steps; a still camera's default multiple of them
# (nerf.train.still_steps) is measured by the bench (docs/results.md).
STEPS += ["--set", "nerf.train.still_steps=1"]


@pytest.fixture(scope="module")
def still_case(tmp_path_factory: pytest.TempPathFactory) -> Path:
    src = tmp_path_factory.mktemp("still_input") / "pull"
    cfg = SynthConfig(
        shape="cavity", deform="pull", still_camera=True, frames=24, width=160, height=128, seed=7
    )
    generate_case(src, cfg)
    wd = tmp_path_factory.mktemp("still_wd")
    assert main(["run", str(src), "--workdir", str(wd), "--quiet", *STEPS]) == 0
    return wd / "pull"


def test_a_still_camera_over_a_pulled_wall_gets_one_pose_and_says_so(still_case: Path):
    poses = PosesView(still_case / "02_poses")
    motion = poses.summary.motion
    assert motion is not None and motion.label == "camera still, tissue moving"
    assert poses.summary.mapper == "still camera"
    assert len(poses.registered) == 24
    first = poses.c2w[poses.registered[0]]
    assert all(np.array_equal(poses.c2w[i], first) for i in poses.registered)
    verdict = poses.verdict()
    assert verdict is not None and verdict.reasons[0].startswith("camera still, tissue moving")


def test_the_tool_masks_leave_the_usable_pixels(still_case: Path):
    ingest = IngestView(still_case / "01_ingest")
    s = ingest.summary
    assert s.tool_masks is not None and 0.0 < s.mean_tool_fraction <= s.max_tool_fraction < 0.5
    frame = ingest.frames[-1]
    tool = ingest.tool_mask(frame.index)
    assert tool is not None and tool.any()
    assert (ingest.mask(frame.index)[tool] == 0).all()


def test_its_field_changes_with_time_and_its_depth_is_one_viewpoints(still_case: Path):
    nerf = NerfView(still_case / "04_nerf").summary
    assert nerf.time_nodes is not None
    assert nerf.depth_supervised is False  # nothing measured its depth: read at the median
    depth = DepthView(still_case / "05_depth")
    assert depth.summary.one_viewpoint
    assert depth.summary.seen_again_share == 0.0  # no pixel was seen from two places
    m = depth.metrics
    assert m is not None and m.median_scaled is not None and m.baselines is not None
    ours = m.median_scaled.abs_rel
    guess = m.baselines["brightness"].median_scaled.abs_rel
    assert ours < 0.8 * guess, (ours, guess)  # measured 0.053 against 0.091, on tissue
    assert m.neighbour_average and m.neighbour_average["psnr"] > 0


def test_its_depth_is_scored_on_tissue_not_on_the_tool(still_case: Path):
    """On a tool the truth is the tool and ours the tissue under it: the scores leave tools
    out and say how much; a frame's score recomputed off its tool matches, with it it does not
    (the rule itself: test_metrics_baselines)."""
    ingest, depth = IngestView(still_case / "01_ingest"), DepthView(still_case / "05_depth")
    m = depth.metrics
    assert m is not None and m.per_frame is not None
    assert m.tool_share_left_out == pytest.approx(ingest.summary.mean_tool_fraction, abs=0.02)
    i = ingest.frames[-1].index
    row = next(r for r in m.per_frame if r["index"] == i)["median_scaled"]
    truth = evaluate.ground_truth_depths(ingest.ground_truth(), ingest, [i])[i]
    tool = ingest.tool_mask(i)
    assert tool is not None and tool.mean() > 0.05
    inside = evaluate.inside_view(ingest)
    off = depth_frame_metrics(depth.depth(i), truth, inside & ~tool)
    on = depth_frame_metrics(depth.depth(i), truth, inside)
    assert row["abs_rel"] == pytest.approx(off["abs_rel"], rel=1e-5)
    # the tool's pixels would change it (measured 0.052 on them too against 0.050 off: ours has
    # depth on few of them, and there it is the tissue behind, about 1.8x the tool's distance)
    assert on["abs_rel"] != pytest.approx(off["abs_rel"], rel=1e-3)


def test_its_surface_is_meshed_at_several_times_and_shown_moving(still_case: Path):
    mesh = MeshView(still_case / "06_mesh")
    times = mesh.time_meshes
    assert sorted(times) == mesh.summary.time_frames and len(times) == 4
    assert min(times) == 0 and max(times) == 23  # spread over the whole clip
    first = np.asarray(mesh.load_time(0).vertices)
    assert all(len(mesh.load_time(f).faces) > 100 for f in times)
    # the tool pulls the wall: a later surface departs from the first one where it was pulled
    from scipy.spatial import cKDTree

    extent = float(np.ptp(first, axis=0).max())
    gaps = [
        float(np.percentile(cKDTree(first).query(np.asarray(mesh.load_time(f).vertices))[0], 99))
        for f in sorted(times)[1:]
    ]
    assert max(gaps) > 0.02 * extent, (gaps, extent)  # measured 3.4-4.0% of the extent
    page = (still_case / "07_report" / "report.html").read_text()
    assert "The surface over time" in page and "data:image/gif;base64," in page
