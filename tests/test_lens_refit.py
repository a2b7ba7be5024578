"""An estimated lens that bends back inside the image is re-fitted as a fisheye: every pixel gets
a ray, and the outer rays' angles come close to the true lens's."""

from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path

import numpy as np
import pytest

from endopipe.stages.camera import Camera, lens_valid_mask
from endopipe.stages.camera.rays import pixel_directions
from endopipe.stages.poses.view import PosesView


def ray_angle_deg(camera: Camera, u: float, v: float) -> float:
    d = pixel_directions(camera, np.array([u]), np.array([v]))[0]
    return float(np.degrees(np.arctan(np.hypot(d[0], d[1]))))


@pytest.fixture(scope="module")
def fisheye_poses(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Camera, str]:
    """A small colon through the synthetic 140-degree fisheye, the lens withheld: posed by the
    default SfM (SIMPLE_RADIAL self-calibrated); and what reached the process's stderr (COLMAP
    writes there itself, past Python)."""
    from typer.testing import CliRunner

    from endopipe.cli import app
    from endopipe.synth import SynthConfig, generate_case

    root = tmp_path_factory.mktemp("fisheye")
    src = root / "src"
    generate_case(src, SynthConfig(seed=7, frames=30, width=192, height=160, lens="fisheye"))
    source = root / "in"
    source.mkdir()
    for part in ("video.mp4", "gt"):
        (source / part).symlink_to((src / part).resolve())
    with tempfile.TemporaryFile() as err:
        saved = os.dup(2)
        os.dup2(err.fileno(), 2)
        try:
            result = CliRunner().invoke(
                app, ["run", str(source), "--workdir", str(root / "w"), "--until", "poses"]
            )
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        err.seek(0)
        stderr = err.read().decode(errors="replace")
    assert result.exit_code == 0, result.output
    return root / "w" / "in" / "02_poses", Camera.load(src / "intrinsics.json"), stderr


def test_the_lens_refit_writes_no_colmap_log_lines(fisheye_poses) -> None:
    stderr = fisheye_poses[2]
    assert not re.search(r"^[IWE]\d{8} ", stderr, re.M), stderr[:500]
    assert "Bundle adjustment report" not in stderr


def test_a_folding_lens_is_refitted_as_a_fisheye_near_the_true_one(fisheye_poses) -> None:
    folder, truth, _ = fisheye_poses
    poses = PosesView(folder)
    refit = json.loads((folder / "manifest.json").read_text())["summary"]["lens_refit"]
    assert (refit["from_model"], refit["to_model"]) == ("SIMPLE_RADIAL", "OPENCV_FISHEYE")
    assert 0 < refit["omega"] < 3 and refit["seconds"] >= 0
    record = poses.summary.lens_refit  # read back typed, and said in words from its fields
    assert record is not None and record.said.startswith("SIMPLE_RADIAL bent back")
    assert f"{record.reprojection_after_px:.3f} px" in record.said
    assert poses.intrinsics.model == "fisheye" and poses.file.model == "OPENCV_FISHEYE"
    assert lens_valid_mask(poses.intrinsics).all()  # every pixel has a ray
    # Along the diagonal, out to 0.8 and 0.9 of the corner's radius: measured 2.0 and 2.5 deg
    # off the true angle (55.1, 62.5); SIMPLE_RADIAL (poses.unfold_lens=false) was 9.9 and 10.2
    # off, and gave the corner no ray.
    far = np.hypot(truth.cx + 0.5, truth.cy + 0.5)
    for share in (0.8, 0.9):
        u = truth.cx + share * (truth.cx + 0.5)
        v = truth.cy + share * (truth.cy + 0.5)
        assert abs(ray_angle_deg(poses.intrinsics, u, v) - ray_angle_deg(truth, u, v)) < 4.0
    # The features it was fitted to reach past the image's half-height, short of the corner.
    assert truth.height / 2 < poses.file.fitted_radius_px < far
