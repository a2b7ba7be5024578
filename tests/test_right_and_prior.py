"""What a user brings beside the input: `--right FOLDER --baseline-mm B` (a rectified right eye,
matched by the number in the file names) and `--depth-prior FOLDER` (depth maps made
elsewhere, relative), on a small synthetic stereo Hamlyn sequence with exact depth.

`--right` on the left eye's plain image folder gives the Hamlyn reader's own stereo depth; the
refusals are one line each and leave no case folder; the depth prior is read at the working
size without inventing pixels, scored beside ours (median-scaled), and its loss is blind to
the prior's scale and shift, and to ours.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from endopipe.cli import main
from endopipe.stages.depth.evaluate import evaluate, ground_truth_depths, prior_maps
from endopipe.stages.depth.metrics_file import DepthMetrics
from endopipe.stages.ingest.prior_frames import resample
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.sources import open_input
from endopipe.stages.nerf.losses import prior_depth
from endopipe.stages.nerf.prior_depth import prior_depth_targets
from endopipe.stages.report.sections.guesses import comparison
from tests.stereo_hamlyn import BASELINE_MM, write_stereo_hamlyn


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """rectified01/ (4 frames, 320x256) and, beside it, K.json (its camera as intrinsics.json)
    and prior/ (the exact depth as .npy, named as the left frames are)."""
    root = tmp_path_factory.mktemp("user_inputs")
    seq = root / "rectified01"
    write_stereo_hamlyn(seq, seed=1, frames=4)
    K = np.loadtxt(seq / "intrinsics.txt")
    (root / "K.json").write_text(
        json.dumps(
            {
                "width": 320,
                "height": 256,
                "fx": K[0, 0],
                "fy": K[1, 1],
                "cx": K[0, 2],
                "cy": K[1, 2],
            }
        )
    )
    truth = open_input(seq).ground_truth()
    assert truth is not None
    (root / "prior").mkdir()
    for i, f in enumerate(sorted((seq / "image01").iterdir())):
        np.save(root / "prior" / f"{f.stem}.npy", truth.depth(i))
    return seq


def run(src: Path, wd: Path, *args: str) -> int:
    return main(["run", str(src), "--workdir", str(wd), "--until", "ingest", *args])


def left_eye(seq: Path, *extra: str) -> list[str]:
    """The options that make the left eye's plain image folder a rectified stereo input."""
    return ["--intrinsics", str(seq.parent / "K.json"), *extra]


def one_line_refusal(capsys: pytest.CaptureFixture[str], code: int, *words: str) -> str:
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, err
    return err


# --------------------------------------------------------------------------------- --right


def test_right_on_an_image_folder_gives_the_hamlyn_readers_stereo_depth(
    seq: Path, tmp_path: Path
) -> None:
    assert run(seq, tmp_path / "a", "--quiet", "--set", "ingest.max_size=160") == 0
    right = ["--right", str(seq / "image02"), "--baseline-mm", str(BASELINE_MM)]
    code = run(
        seq / "image01",
        tmp_path / "b",
        "--quiet",
        "--set",
        "ingest.max_size=160",
        *left_eye(seq, *right),
    )
    assert code == 0
    reader = IngestView(tmp_path / "a" / "rectified01" / "01_ingest")
    ours = IngestView(tmp_path / "b" / "image01" / "01_ingest")
    assert ours.has_stereo and ours.summary.stereo_baseline_mm == pytest.approx(BASELINE_MM)
    assert ours.summary.stereo.startswith("--right")
    assert reader.indices == ours.indices == [0, 1, 2, 3]
    for i in ours.indices:
        a, b = reader.stereo_depth(i), ours.stereo_depth(i)
        assert a is not None and b is not None and (a > 0).mean() > 0.5
        np.testing.assert_array_equal(a, b)
    info = json.loads((tmp_path / "b" / "image01" / "case.json").read_text())
    assert info["right"] == str((seq / "image02").resolve()) and info["baseline_mm"] == BASELINE_MM


def test_right_images_two_pixels_larger_are_cropped_centred(seq: Path, tmp_path: Path) -> None:
    """Padded by one pixel on every side: cropped back, the same depth as the exact pair."""
    padded = tmp_path / "right"
    padded.mkdir()
    for f in sorted((seq / "image02").iterdir()):
        img = cv2.imread(str(f))
        cv2.imwrite(
            str(padded / f"{f.stem}.png"), cv2.copyMakeBorder(img, 1, 1, 1, 1, cv2.BORDER_REFLECT)
        )
    pairs = open_input(
        seq / "image01", seq.parent / "K.json", added=added(right=padded, baseline_mm=5.0)
    ).stereo
    assert pairs is not None
    first = sorted((seq / "image02").iterdir())[0]
    expect = cv2.cvtColor(cv2.imread(str(first)), cv2.COLOR_BGR2RGB)
    got = pairs.right(0)
    assert got is not None and got.shape == expect.shape
    # The JPEG was decoded once and written losslessly: the crop is exactly the original.
    np.testing.assert_array_equal(got, expect)


def added(**kw):
    from endopipe.stages.io.added import AddedInputs

    return AddedInputs(**kw)


def test_refusals_are_one_line_and_leave_no_case(
    seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    left, right = seq / "image01", str(seq / "image02")
    wd = tmp_path / "wd"
    one_line_refusal(capsys, run(left, wd, *left_eye(seq, "--right", right)), "--baseline-mm")
    code = run(left, wd, *left_eye(seq, "--right", right, "--baseline-mm", "500"))
    one_line_refusal(capsys, code, "500", "outside")
    odd = tmp_path / "odd"
    shutil.copytree(seq / "image02", odd)
    victim = sorted(odd.iterdir())[2]
    cv2.imwrite(str(victim), cv2.resize(cv2.imread(str(victim)), (300, 240)))
    code = run(left, wd, *left_eye(seq, "--right", str(odd), "--baseline-mm", "5"))
    one_line_refusal(capsys, code, victim.name, "300x240", "320x256")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    for f in sorted((seq / "image02").iterdir()):
        shutil.copy(f, elsewhere / f"right_{int(f.stem) + 100}.jpg")
    code = run(left, wd, *left_eye(seq, "--right", str(elsewhere), "--baseline-mm", "5"))
    one_line_refusal(capsys, code, "no right image matches a frame")
    code = run(left, wd, *left_eye(seq, "--baseline-mm", "5"))
    one_line_refusal(capsys, code, "--baseline-mm goes with --right")
    assert not wd.exists() or not any(wd.iterdir())  # nothing half-written


def test_right_on_an_input_with_its_own_rig_wins_and_says_so(
    seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Hamlyn's reader knows its rig (5 mm): --right replaces its right views, its baseline is
    kept when none is given; a --baseline-mm given replaces that too."""
    flipped = tmp_path / "right"
    flipped.mkdir()
    for f in sorted((seq / "image01").iterdir()):  # the left eye as the "right": disparity 0
        shutil.copy(f, flipped / f.name)
    source = open_input(seq, added=added(right=flipped))
    assert source.stereo is not None and source.stereo.source.startswith("--right")
    assert source.stereo.baseline_mm == pytest.approx(BASELINE_MM)
    assert any("replaces the right views" in n for n in source.notes)
    source = open_input(seq, added=added(right=flipped, baseline_mm=4.2))
    assert source.stereo is not None and source.stereo.baseline_mm == pytest.approx(4.2)
    assert open_input(seq).digest() != source.digest()  # the flag changes the ingest key
    assert run(seq, tmp_path / "wd", "--right", str(flipped), "--set", "ingest.max_size=96") == 0
    said = " ".join(capsys.readouterr().err.split())
    assert "replaces the right views the input came with" in said


# ---------------------------------------------------------------------------- --depth-prior


def test_ingest_writes_the_prior_at_the_working_size_and_the_view_reads_it(
    seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    prior = tmp_path / "prior"
    shutil.copytree(seq.parent / "prior", prior)
    first = sorted(prior.iterdir())[0]
    d = np.load(first)
    d[:40, :40] = np.nan  # unknown stays unknown
    d[40:80, :40] = np.inf
    np.save(first, d)
    code = run(seq, tmp_path, "--depth-prior", str(prior), "--set", "ingest.max_size=160")
    assert code == 0
    assert "depth prior for 4 of 4 frames" in " ".join(capsys.readouterr().err.split())
    view = IngestView(tmp_path / "rectified01" / "01_ingest")
    assert view.has_depth_prior and view.summary.depth_prior_frames == 4
    truth = open_input(seq).ground_truth()
    for i in view.indices:
        got = view.depth_prior(i)
        assert got is not None and got.shape == (128, 160) and got.dtype == np.float32
        assert np.isfinite(got).all()
        expect = resample(truth.depth(view.frame(i).source_index), (160, 128))
        known = got > 0
        np.testing.assert_allclose(got[known], expect[known], rtol=1e-5)
    first_map = view.depth_prior(0)
    assert (first_map[:20, :20] == 0).all() and (first_map[20:40, :20] == 0).all()
    assert (first_map[60:, 40:] > 0).mean() > 0.95
    frames = json.loads((view.folder / "frames.json").read_text())
    assert frames["depth_prior"] == str(prior.resolve())
    assert frames["frames"][0]["depth_prior"] == "depth_prior/000000.npy"


def test_resampling_invents_no_depth() -> None:
    """Shrinking averages only known pixels (half the footprint at least); growing repeats."""
    d = np.array([[1, 1, 0, 0], [1, 1, 0, 0], [2, 0, 0, 0], [2, 0, 0, 5]], np.float32)
    small = resample(d, (2, 2))
    np.testing.assert_allclose(small, [[1, 0], [2, 0]])
    big = resample(np.array([[1, 0]], np.float32), (4, 2))
    np.testing.assert_array_equal(big, [[1, 1, 0, 0], [1, 1, 0, 0]])


def test_a_16_bit_png_prior_is_read_and_an_8_bit_one_refused(
    seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Hamlyn's depth01/ (uint16 mm) is a 16-bit PNG prior; 8-bit and other shapes refused."""
    source = open_input(seq / "image01", added=added(depth_prior=seq / "depth01"))
    assert source.depth_prior is not None
    first = source.depth_prior.read(0, (320, 256))
    raw = cv2.imread(str(sorted((seq / "depth01").iterdir())[0]), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    np.testing.assert_array_equal(first, raw.astype(np.float32))
    eight = tmp_path / "eight"
    eight.mkdir()
    cv2.imwrite(str(eight / "0000000001.png"), np.full((256, 320), 9, np.uint8))
    code = run(seq / "image01", tmp_path / "wd", "--depth-prior", str(eight))
    one_line_refusal(capsys, code, "8-bit")
    odd = tmp_path / "odd"
    odd.mkdir()
    np.save(odd / "0000000001.npy", np.ones((100, 100), np.float32))
    code = run(seq / "image01", tmp_path / "wd", "--depth-prior", str(odd))
    one_line_refusal(capsys, code, "100x100", "320x256")
    none = tmp_path / "none"
    none.mkdir()
    np.save(none / "frame_77.npy", np.ones((256, 320), np.float32))
    code = run(seq / "image01", tmp_path / "wd", "--depth-prior", str(none))
    one_line_refusal(capsys, code, "no depth map")
    # A lower resolution of the same shape is the network's usual output: accepted.
    half = tmp_path / "half"
    half.mkdir()
    np.save(half / "0000000001.npy", np.ones((128, 160), np.float32))
    assert open_input(seq / "image01", added=added(depth_prior=half)).depth_prior is not None


def test_the_exact_prior_scores_near_perfect_beside_ours(seq: Path, tmp_path: Path) -> None:
    """The exact depth at another scale (as a network's would be): median scaling makes it
    near perfect, in the depth stage's baselines and the report's table; no unscaled block."""
    scaled = tmp_path / "prior"
    scaled.mkdir()
    for f in sorted((seq.parent / "prior").iterdir()):
        np.save(scaled / f.name, 0.037 * np.load(f))
    assert run(seq, tmp_path, "--quiet", "--depth-prior", str(scaled)) == 0
    view = IngestView(tmp_path / "rectified01" / "01_ingest")
    gt = view.ground_truth()
    ids = view.indices
    truth = ground_truth_depths(gt, view, ids)
    rng = np.random.default_rng(0)
    ours = {i: truth[i] * rng.uniform(0.8, 1.25, truth[i].shape).astype(np.float32) for i in ids}
    prior = prior_maps(view, ids)
    assert sorted(prior) == ids
    scores = evaluate(gt, view, ours, truth, {}, metric=True, prior=prior)
    block = scores["baselines"]["depth_prior"]
    assert block["median_scaled"]["abs_rel"] < 1e-4
    assert block["median_scaled"]["coverage"] > 0.95
    assert scores["median_scaled"]["abs_rel"] > 0.05  # ours, noisy: the table has a contrast
    assert "unscaled" not in block and "unscaled" in scores["baselines"]["radial"]
    table = comparison(DepthMetrics.model_validate(scores))
    assert table is not None and "your depth prior" in table.names
    said = " ".join(table.verdicts)
    assert "than your depth prior (" in said


# ----------------------------------------------------------------------------- the loss


def test_the_prior_loss_ignores_the_priors_scale_and_shift_and_ours() -> None:
    gen = torch.Generator().manual_seed(0)
    depth = 5 + torch.rand(3, 64, generator=gen) * 10
    prior = 2 + torch.rand(3, 64, generator=gen)
    base = prior_depth(depth, prior)
    assert base > 1e-3
    # Each frame its own scale and shift: the prior of frame k is a_k * p + b_k.
    a = torch.tensor([[0.01], [3.0], [250.0]])
    b = torch.tensor([[-7.0], [0.0], [1e3]])
    assert prior_depth(depth, a * prior + b) == pytest.approx(float(base), rel=1e-4)
    assert prior_depth(4.0 * depth, prior) == pytest.approx(float(base), rel=1e-4)
    assert float(prior_depth(depth, a * depth + b)) < 1e-8  # the prior is our depth's shape


def test_the_prior_loss_pulls_depth_towards_the_priors_shape() -> None:
    """Gradient steps on depth alone: it comes to follow the prior up to scale and shift."""
    gen = torch.Generator().manual_seed(1)
    prior = torch.rand(2, 128, generator=gen)
    depth = (10 + torch.rand(2, 128, generator=gen)).requires_grad_(True)
    opt = torch.optim.Adam([depth], lr=0.02)
    first = float(prior_depth(depth, prior).detach())
    for _ in range(300):
        opt.zero_grad()
        prior_depth(depth, prior).backward()
        opt.step()
    assert float(prior_depth(depth, prior).detach()) < 0.05 * first
    for k in range(2):
        r = np.corrcoef(depth[k].detach().numpy(), prior[k].numpy())[0, 1]
        assert r > 0.95


def test_the_fields_prior_rays_are_drawn_frame_by_frame(seq: Path, tmp_path: Path) -> None:
    assert run(seq, tmp_path, "--quiet", "--depth-prior", str(seq.parent / "prior")) == 0
    view = IngestView(tmp_path / "rectified01" / "01_ingest")
    positions = {i: p for p, i in enumerate(view.indices[:3])}
    usable = {i: view.mask(i) > 127 for i in positions}
    rays = prior_depth_targets(view.depth_prior, positions, usable, 500, 128, torch.device("cpu"))
    assert rays is not None and rays.frame == [0, 1, 2] and len(rays) == 1500
    frame, u, v, p = rays.sample(4, 32, torch.Generator().manual_seed(0))
    assert frame.shape == (128,) and (frame.view(4, 32) == frame.view(4, 32)[:, :1]).all()
    for f, uu, vv, pp in zip(frame.tolist(), u.tolist(), v.tolist(), p.tolist(), strict=True):
        i = view.indices[f]
        assert view.depth_prior(i)[int(vv), int(uu)] == pytest.approx(pp)
    assert not view.has_stereo or view.stereo_depth(0) is not None


# ------------------------------------------------------------------ batch: a folder per case
def test_batch_gives_each_case_its_own_prior_and_refuses_a_root_with_none(
    seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`batch --depth-prior PRIORS`: PRIORS/<case>/ goes with that case only (here two
    sequences, the second's maps 3x the first's), a case without one runs without and is
    named, and a PRIORS with no folder for any case is refused in one line, running nothing."""
    data, priors = tmp_path / "hamlyn", tmp_path / "priors"
    for name, scale in (("rectified01", 1.0), ("rectified02", 3.0)):
        shutil.copytree(seq, data / name)
        (priors / name).mkdir(parents=True)
        for f in sorted((seq.parent / "prior").iterdir()):
            np.save(priors / name / f.name, np.load(f) * scale)
    shutil.copytree(seq, data / "rectified03")  # no prior of its own
    wd = tmp_path / "runs"
    args = ["batch", str(data), "--workdir", str(wd), "--until", "ingest", "--jobs", "1"]
    assert main([*args, "--depth-prior", str(priors)]) == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "--depth-prior: no folder for rectified03" in err, err
    first, second, third = (
        IngestView(wd / n / "01_ingest") for n in ("rectified01", "rectified02", "rectified03")
    )
    assert first.file.depth_prior == str((priors / "rectified01").resolve())
    assert second.file.depth_prior == str((priors / "rectified02").resolve())
    assert not third.has_depth_prior
    ratio = (
        second.depth_prior(0)[first.depth_prior(0) > 0]
        / first.depth_prior(0)[first.depth_prior(0) > 0]
    )
    np.testing.assert_allclose(ratio, 3.0, rtol=1e-5)

    wrong = tmp_path / "elsewhere"
    (wrong / "other").mkdir(parents=True)
    one_line_refusal(
        capsys,
        main([*args, "--workdir", str(tmp_path / "runs2"), "--depth-prior", str(wrong)]),
        "holds no folder named after a case",
    )
    assert not (tmp_path / "runs2" / "rectified01").exists()
