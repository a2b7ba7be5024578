"""The pipeline on data set layouts: one synthetic colon written as C3VD, SimCol3D and an
endopipe case folder, run to the NeRF: each is posed and scored against its own truth like a
case folder (the readers' units: tests/test_datasets.py)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile
from scipy.spatial.transform import Rotation

from endopipe.stages.io.cases import detect_format
from tests.test_datasets import FLIP_Y

#: Small pipeline settings: poses, centerline and a short NeRF (enough for held-out metrics).
QUICK = ["--until", "nerf", "--quiet", "--set", "nerf.train.steps=150"]
QUICK += ["--set", "nerf.train.time_budget_s=null", "--set", "nerf.train.threads=1"]
QUICK += ["--set", "nerf.train.still_steps=1"]  # a still input trains the steps above too
#: Measured on the 16-frame colon below, in every layout: ATE 0.93% of the path, held-out
#: unscaled AbsRel 0.093, sequence scale 1.018 (about 30 s a run on 2 cores).
ATE_PERCENT_MAX = 2.0
UNSCALED_ABS_REL_MAX = 0.15


@pytest.fixture(scope="module")
def synth_case(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small synthetic colon (16 frames, 160x128) with exact depth and poses, in mm."""
    from endopipe.synth import SynthConfig, generate_case

    case = tmp_path_factory.mktemp("synth") / "colon"
    generate_case(case, SynthConfig(seed=0, frames=16, width=160, height=128))
    return case


def case_truth(case: Path, full_scale_mm: float) -> tuple[list[Path], list[np.ndarray], list]:
    """The case's frames, its GT depth and poses scaled (a similarity of the whole scene) so
    that every depth fits the data set's encoding range."""
    frames = sorted((case / "frames").glob("*.png"))
    depths = [np.load(case / "gt" / "depth" / f"{i:06d}.npy") for i in range(len(frames))]
    scale = 0.9 * full_scale_mm / max(float(d.max()) for d in depths)
    poses = []
    for p in json.loads((case / "gt" / "poses.json").read_text())["poses"]:
        c2w = np.array(p, dtype=np.float64)
        c2w[:3, 3] *= scale
        poses.append(c2w)
    return frames, [d * scale for d in depths], poses


def c3vd_from_case(case: Path, seq: Path) -> Path:
    """The case as a C3VD sequence: NNNN_color.png, NNNN_depth.tiff (uint16, mm * 65535 / 100),
    pose.txt (column-major c2w, mm) and an endopipe intrinsics.json beside them."""
    seq.mkdir(parents=True)
    frames, depths, poses = case_truth(case, 100.0)
    for i, (frame, depth) in enumerate(zip(frames, depths, strict=True)):
        shutil.copy(frame, seq / f"{i:04d}_color.png")
        raw = np.round(depth / 100.0 * 65535.0).astype(np.uint16)
        tifffile.imwrite(seq / f"{i:04d}_depth.tiff", raw)
    lines = [",".join(repr(float(v)) for v in c2w.T.reshape(-1)) for c2w in poses]
    (seq / "pose.txt").write_text("\n".join(lines) + "\n")
    shutil.copy(case / "intrinsics.json", seq / "intrinsics.json")
    return seq


def simcol_from_case(case: Path, colon: Path) -> Path:
    """The case as a SimCol3D sequence: Frames_S1/FrameBuffer_NNNN.png (RGBA) and Depth_NNNN.png
    (png / 255 / 256 * 20 cm), Unity (left-handed, cm) positions and quaternions, cam.txt."""
    frames_dir = colon / "Frames_S1"
    frames_dir.mkdir(parents=True)
    frames, depths, poses = case_truth(case, 200.0)
    for i, (frame, depth) in enumerate(zip(frames, depths, strict=True)):
        bgra = cv2.cvtColor(cv2.imread(str(frame)), cv2.COLOR_BGR2BGRA)
        cv2.imwrite(str(frames_dir / f"FrameBuffer_{i:04d}.png"), bgra)
        raw = np.round(depth / 10.0 / 20.0 * 255.0 * 256.0).astype(np.uint16)
        cv2.imwrite(str(frames_dir / f"Depth_{i:04d}.png"), raw)
    pos_lines, rot_lines = [], []
    for c2w in poses:
        unity = FLIP_Y @ c2w @ FLIP_Y
        pos_lines.append(" ".join(repr(float(v)) for v in unity[:3, 3] / 10.0))
        quat_xyzw = Rotation.from_matrix(unity[:3, :3]).as_quat()
        rot_lines.append(" ".join(repr(float(v)) for v in quat_xyzw))
    (colon / "SavedPosition_S1.txt").write_text("\n".join(pos_lines) + "\n")
    (colon / "SavedRotationQuaternion_S1.txt").write_text("\n".join(rot_lines) + "\n")
    k = json.loads((case / "intrinsics.json").read_text())
    (colon / "cam.txt").write_text(f"{k['fx']!r} 0 {k['cx']!r} 0 {k['fy']!r} {k['cy']!r} 0 0 1\n")
    return frames_dir


def run_until_nerf(source: Path, workdir: Path) -> Path:
    from endopipe.cli import main

    assert main(["run", str(source), "--workdir", str(workdir), *QUICK]) == 0
    (case,) = [p for p in workdir.iterdir() if (p / "case.json").is_file()]
    return case


def stage_summary(case: Path, folder: str) -> dict:
    return json.loads((case / folder / "manifest.json").read_text())["summary"]


def nerf_metrics(case: Path) -> dict:
    return json.loads((case / "04_nerf" / "metrics.json").read_text())


@pytest.fixture(scope="module")
def case_run(synth_case: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The reference: the same colon as an endopipe case folder."""
    return run_until_nerf(synth_case, tmp_path_factory.mktemp("wd"))


# 2 min for both (a colon run to the NeRF three times): the readers' round trips above and
# test_c3vd_layout's run keep the data sets in the default suite
@pytest.mark.slow
@pytest.mark.parametrize("layout", ["c3vd", "simcol3d"])
def test_data_set_sequences_are_aligned_and_evaluated_like_case_folders(
    synth_case: Path, case_run: Path, tmp_path: Path, layout: str
) -> None:
    """A C3VD or SimCol3D sequence goes through the same ground-truth door as a case folder:
    its poses are moved onto the ground truth (mm, with an ATE) and the NeRF's held-out depth is
    measured against the data set's depth maps, with the case folder's figures (the scene is
    the same up to a scale, which neither measure sees)."""
    if layout == "c3vd":
        source = c3vd_from_case(synth_case, tmp_path / "cecum_t1_a")
    else:
        source = simcol_from_case(synth_case, tmp_path / "SyntheticColon_I")
    assert detect_format(source) == layout
    case = run_until_nerf(source, tmp_path / "wd")

    poses = stage_summary(case, "02_poses")
    assert poses["registered_fraction"] >= 0.9, poses
    assert poses["aligned_to_gt"] and poses["metric"], poses
    assert "ate_mm" in poses and poses["ate_percent_of_path"] < ATE_PERCENT_MAX, poses

    reference = stage_summary(case_run, "02_poses")
    assert reference["aligned_to_gt"]
    assert poses["ate_percent_of_path"] == pytest.approx(reference["ate_percent_of_path"], abs=0.1)

    metrics = nerf_metrics(case)
    assert metrics["depth_frames"] == len(metrics["heldout"]) >= 2, metrics
    depth = metrics["depth"]
    assert set(depth) == {"median_scaled", "sequence_scaled", "unscaled"}
    # in the truth's millimetres: even without any rescaling the depth is close to the truth
    assert depth["unscaled"]["abs_rel"] < UNSCALED_ABS_REL_MAX, depth
    assert 0.9 < depth["sequence_scaled"]["scale"] < 1.1, depth
    want = nerf_metrics(case_run)["depth"]
    for protocol in ("median_scaled", "unscaled"):
        assert depth[protocol]["abs_rel"] == pytest.approx(want[protocol]["abs_rel"], abs=0.01)
