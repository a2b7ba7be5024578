"""C3VD as it ships: its omnidirectional calibration becomes the lens (a fitted OpenCV fisheye,
its residual said), and its registered model is the truth the mesh stage scores against."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from endopipe.commands.synth import other_layout
from endopipe.stages.camera import image_directions
from endopipe.stages.io.c3vd import decode_depth, encode_depth
from endopipe.stages.io.datasets import detect_dataset, open_dataset, open_ground_truth
from endopipe.stages.io.ocam import fit_fisheye, ocam_from_camera, read_ocam, write_ocamcalib
from endopipe.stages.mesh.config import MeshConfig
from endopipe.stages.mesh.evaluation import (
    case_ground_truth,
    evaluate_against_gt,
    ground_truth_mesh,
)
from endopipe.stages.surface.mesh import read_mesh
from endopipe.synth import SynthConfig, generate_case
from endopipe.synth.generate import intrinsics_for

# C3VD's published CF-HQ190L calibration (DurrLab/C3VD python/exampleDataLoader.py), written as
# its registration program's config.ini reads it (RenderingModule::loadParams).
C3VD_CONFIG = """width=1350
height=1080
cx=678.544839263292
cy=542.975887548343
a0=769.243600037458
a1=0.0
a2=-0.000812770624150226
a3=6.25674244578925e-07
a4=-1.19662182144280e-09
c=0.999986882249990
d=0.00288273829525059
e=-0.00296316513429569
"""


@pytest.fixture(scope="module")
def case(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SynthConfig]:
    out = tmp_path_factory.mktemp("c3vd") / "seq"
    cfg = SynthConfig(seed=3, frames=4, width=64, height=48, lens="fisheye")
    generate_case(out, cfg, layout=other_layout("c3vd"))
    return out, cfg


def angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip((a * b).sum(-1), -1.0, 1.0)))


def test_the_calibration_is_the_lens(case: tuple[Path, SynthConfig]) -> None:
    path, cfg = case
    assert detect_dataset(path) == "c3vd"
    source = open_dataset(path, "c3vd")
    k, truth = source.intrinsics, intrinsics_for(cfg)
    assert k is not None and k.model == "fisheye"
    # measured: 0.001 px and 1e-4 deg apart; a lens read wrongly (axes, sign) is degrees off
    assert abs(k.fx - truth.fx) < 0.01 * truth.fx and abs(k.cx - truth.cx) < 0.05
    assert angles_deg(image_directions(k), image_directions(truth)).max() < 0.05
    assert "px RMS" in source.notes[0] and "calib_results.txt" in source.notes[0]


def test_c3vds_own_lens_ships_in_its_calibration_folder(tmp_path: Path) -> None:
    """`synth --layout c3vd --lens c3vd`: frames rendered through C3VD's published lens, its
    calibration written as C3VD ships it (a params folder beside the sequence, a format file and
    a values file): the reader finds it, reads the published numbers, and its lens is the one the
    frames were rendered through."""
    from endopipe.synth.c3vd_lens import CF_HQ190L, PARAMS_FOLDER, VALUES_FILE, c3vd_lens

    seq = tmp_path / "cecum_t1_a"
    cfg = SynthConfig(seed=2, frames=2, width=80, height=64, lens="c3vd")
    generate_case(seq, cfg, layout=other_layout("c3vd", lens="c3vd"))
    assert not (seq / "calib_results.txt").exists()
    values = tmp_path / PARAMS_FOLDER / VALUES_FILE
    lens = read_ocam(values)
    assert "named by" in lens.source and lens.width == 80
    assert lens.stretch == c3vd_lens(80, 64).stretch
    assert lens.poly[0] == pytest.approx(CF_HQ190L["a0"] * 80 / 1350, rel=1e-12)
    source = open_dataset(seq, "c3vd")
    k, truth = source.intrinsics, intrinsics_for(cfg)
    assert k is not None and VALUES_FILE in source.notes[0]
    # the same fit of the same numbers (written to 15 digits): 1.5e-6 deg apart
    assert angles_deg(image_directions(k), image_directions(truth)).max() < 1e-4


def test_the_model_mesh_is_the_mesh_stage_truth(case: tuple[Path, SynthConfig]) -> None:
    path, cfg = case
    gt = case_ground_truth(path)
    mesh_file = ground_truth_mesh(gt)
    assert mesh_file == path / "coverage_mesh.obj"
    model, scene = read_mesh(mesh_file), read_mesh(path / "gt" / "mesh.ply")
    assert np.allclose(model.vertices, scene.vertices, atol=1e-4)
    gt_poses = dict(enumerate(open_ground_truth(path).poses()))
    k = open_dataset(path, "c3vd").intrinsics
    poses = SimpleNamespace(
        registered=list(gt_poses), c2w=gt_poses, metric=True, in_gt_frame=True, intrinsics=k
    )
    cfg_mesh = MeshConfig(eval_samples=3_000, eval_occlusion=False)
    # the model moved 0.5 mm: the score finds the truth in its frame and measures the shift
    moved = type(model)(model.vertices + [0.0, 0.5, 0.0], model.faces, None)
    off = evaluate_against_gt(moved, poses, mesh_file, gt_poses, 60.0, cfg_mesh)
    assert off["evaluated"] and off["aligned"] == "gt_frame"
    assert 0.1 < off["chamfer"] < 0.6


def test_clamped_depth_is_unknown() -> None:
    raw = encode_depth(np.array([0.0, 25.0, 150.0]))
    assert raw[2] == 65535
    assert np.allclose(decode_depth(raw), [0.0, 25.0, 0.0], atol=2e-3)


def test_c3vd_published_calibration_fits_a_fisheye(tmp_path: Path) -> None:
    (tmp_path / "config.ini").write_text(C3VD_CONFIG)
    lens = read_ocam(tmp_path / "config.ini")
    fit = fit_fisheye(lens)
    # measured 1.46 px RMS (2.5 px at most) at 1350x1080: the stretch's skew (d, e ~ 0.003),
    # which OpenCV's fisheye has no term for
    assert fit.rms_px < 2.0 and fit.max_px < 3.5 and fit.pixel_share > 0.95
    assert abs(fit.camera.fx - 769.2) < 5 and abs(fit.camera.cx - 678.5) < 1
    assert fit_fisheye(lens.scaled(320, 256)).rms_px < 0.5  # measured 0.34 at working size


def test_one_line_values_take_c_as_the_affine_value_near_one(tmp_path: Path) -> None:
    values = (
        "1350 1080 678.54 542.98 769.24 -0.00081277 6.2567e-07 -1.1966e-09 0.0029 0.99999 -0.003"
    )
    (tmp_path / "cfhq190l_omnidirectional_values.txt").write_text(values + "\n")
    lens = read_ocam(tmp_path / "cfhq190l_omnidirectional_values.txt")
    assert lens.stretch == [[0.99999, -0.003], [0.0029, 1.0]]
    assert lens.poly[0] == 769.24 and lens.width == 1350


def test_calibration_folder_as_c3vd_ships_it_reads_the_values_by_their_names(tmp_path: Path):
    """C3VD's `cfhq190l_omnidirectional_params/` beside the sequences holds a format file (the
    fields' names) and a values file: the values are found (not the format file, which holds no
    numbers), and read by the names the format file gives them, here with d and e in an order the
    name-less guess would get the other way round."""
    from endopipe.stages.io.c3vd import find_calibration

    params = tmp_path / "cfhq190l_omnidirectional_params"
    params.mkdir()
    (params / "cfhq190l_omnidirectional_format.txt").write_text(
        "Width Height cx cy a0 a2 a3 a4 e c d\n"
    )
    (params / "cfhq190l_omnidirectional_values.txt").write_text(
        "1350 1080 678.54 542.98 769.24 -0.00081277 6.2567e-07 -1.1966e-09 -0.003 0.99999 0.0029\n"
    )
    seq = tmp_path / "cecum_t1_a"
    seq.mkdir()
    found = find_calibration(seq)
    assert found == params / "cfhq190l_omnidirectional_values.txt"
    lens = read_ocam(found)
    assert lens.stretch == [[0.99999, -0.003], [0.0029, 1.0]]
    assert lens.cx == 678.54 and lens.poly[0] == 769.24 and "format" in lens.source


def test_ocamcalib_export_reads_with_its_axes(tmp_path: Path) -> None:
    text = """#polynomial coefficients for the DIRECT mapping function (ocam_model.ss in MATLAB).

5 -2.716972e+02 0.000000e+00 -2.741744e-06 1.840940e-06 -8.024838e-10

#polynomial coefficients for the inverse mapping function (ocam_model.invpol in MATLAB).

3 583.4 470.8 97.1

#center: "row" and "column", starting from 0 (C convention)

700.5 729.0

#affine parameters "c", "d", "e"

1.001407 -0.000818 0.000221

#image size: "height" and "width"

1400 1440
"""
    (tmp_path / "calib_results.txt").write_text(text)
    lens = read_ocam(tmp_path / "calib_results.txt")
    assert (lens.cx, lens.cy, lens.width, lens.height) == (729.0, 700.5, 1440, 1400)
    assert lens.poly[0] == pytest.approx(271.6972)  # looking forward
    centre = lens.directions(np.array(lens.cx), np.array(lens.cy))
    assert centre[2] == pytest.approx(1.0)


@pytest.mark.parametrize("model, dist", [("pinhole", []), ("fisheye", [-0.05, 0.01, 0.0, 0.0])])
def test_a_working_size_lens_survives_the_calibration_file(tmp_path: Path, model, dist) -> None:
    """320x256, as the bench writes it: the polynomial keeps the focal length, and the fisheye
    fitted to it puts every ray where the camera does (a pinhole included: an equidistant
    fisheye with k = 0 is not one)."""
    from endopipe.stages.camera import Camera
    from endopipe.stages.camera.projection import project_camera

    cam = Camera(width=320, height=256, fx=160, fy=160, cx=159.5, cy=127.5, model=model, dist=dist)
    write_ocamcalib(tmp_path / "calib_results.txt", ocam_from_camera(cam))
    lens = read_ocam(tmp_path / "calib_results.txt")
    assert abs(abs(lens.poly[0]) - 160.0) < 2.0  # measured 160.0 (was 7e-4: cut off)
    fit = fit_fisheye(lens)
    assert fit.rms_px < 0.05  # measured 0.00
    u, v = np.meshgrid(np.arange(0, 320, 16.0), np.arange(0, 256, 16.0))
    rays = lens.directions(u.ravel(), v.ravel())
    uv, _ = project_camera(fit.camera, rays)
    assert np.abs(uv - np.stack([u.ravel(), v.ravel()], -1)).max() < 0.1
    # an OpenCV fisheye holds a pinhole only with k != 0 (COLMAP reads k = 0 as equidistant)
    assert model != "pinhole" or abs(fit.camera.dist[0]) > 0.1


def test_the_run_says_which_calibration_became_the_lens(
    case: tuple[Path, SynthConfig], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from endopipe.cli import main

    path, _ = case
    assert main(["run", str(path), "--workdir", str(tmp_path), "--until", "ingest"]) == 0
    said = capsys.readouterr()
    out = " ".join((said.out + said.err).split())
    assert out.count("px RMS") == 1 and "calib_results.txt" in out
