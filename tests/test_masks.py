"""Field-of-view and specular masks, checked on real endoscopy frames and on synthetic ones.

Real data live in /work/shared/data (see the PROVENANCE.md files there); tests that need a
folder skip when it is missing. Reference regions are defined independently of the code under
test: from the mean of a whole sequence, or from plain pixel thresholds.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.stages.ingest.masks import (
    FovConfig,
    SpecularConfig,
    combine,
    fov_mask,
    fov_mask_for_sequence,
    specular_mask,
)

DATA = Path("/work/shared/data")
C3VD = DATA / "c3vd_v3_preview" / "rgb"
KVASIR = DATA / "kvasir_speculars" / "frames"
LAPARO = DATA / "laparoscopy_rvimlab"


def _read_rgb(path: Path) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def _folder(path: Path) -> list[Path]:
    files = sorted(path.glob("*.png"))
    if not files:
        pytest.skip(f"no data in {path}")
    return files


def _inner_region(frames: list[np.ndarray], level: int, erode_px: int) -> np.ndarray:
    """The lit region of a sequence, independently of fov_mask: the mean frame's grey above
    `level`, its largest component, eroded (the image edge counts as outside)."""
    mean = np.mean([cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames], axis=0)
    lit = (mean > level).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(lit, connectivity=8)
    lit = (labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).astype(np.uint8)
    k = np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8)
    return cv2.erode(lit, k, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0


def _kept(mask: np.ndarray, region: np.ndarray) -> float:
    return float((mask[region] > 0).mean())


# --- field of view: C3VD (octagonal colonoscope) ----------------------------------------------


@pytest.fixture(scope="module")
def c3vd() -> list[np.ndarray]:
    return [_read_rgb(p) for p in _folder(C3VD)]


CORNER = 12  # side of the patch checked at each image corner (the cut corners are ~80 px)


def _corners(mask: np.ndarray) -> list[np.ndarray]:
    c = CORNER
    return [mask[2 : 2 + c, 2 : 2 + c], mask[2 : 2 + c, -2 - c : -2],
            mask[-2 - c : -2, 2 : 2 + c], mask[-2 - c : -2, -2 - c : -2]]  # fmt: skip


def test_c3vd_every_frame_is_an_octagon_with_black_corners(c3vd):
    inner = _inner_region(c3vd, level=40, erode_px=4)
    border = np.mean([f.max(axis=2) for f in c3vd], axis=0) < 25
    for i, rgb in enumerate(c3vd):
        mask, shape = fov_mask(rgb, FovConfig())
        assert mask.dtype == np.uint8 and mask.shape == rgb.shape[:2]
        assert set(np.unique(mask)) <= {0, 255}
        assert shape == "octagon", f"frame {i}: {shape}"
        assert all((c == 0).all() for c in _corners(mask)), f"frame {i}: corner kept"
        assert _kept(mask, inner) >= 0.95, f"frame {i}: inner region cut"
        assert (mask[border] > 0).mean() < 0.01, f"frame {i}: border kept"


def test_c3vd_sequence_mask(c3vd):
    mask, shape = fov_mask_for_sequence(c3vd, FovConfig())
    assert shape == "octagon"
    assert all((c == 0).all() for c in _corners(mask))
    assert _kept(mask, _inner_region(c3vd, level=40, erode_px=4)) >= 0.98


# --- field of view: laparoscope (circle), phantom and synthetic (no border) --------------------


@pytest.fixture(scope="module")
def laparoscopy() -> list[np.ndarray]:
    av = pytest.importorskip("av")
    video = LAPARO / "endo.mp4"
    if not video.exists():
        pytest.skip(f"missing {video}")
    frames = []
    with av.open(str(video)) as container:
        for i, frame in enumerate(container.decode(video=0)):
            if i % 25 == 0:
                frames.append(frame.to_ndarray(format="rgb24"))
            if len(frames) == 8:
                break
    return frames


def test_laparoscope_is_a_circle_covering_the_disc(laparoscopy):
    for i, rgb in enumerate(laparoscopy):
        mask, shape = fov_mask(rgb, FovConfig())
        assert shape == "circle", f"frame {i}: {shape}"
        disc = _inner_region([rgb], level=30, erode_px=4)
        # The disc's own dark patches (shadowed liver) are in the mask too: only check the lit.
        assert _kept(mask, disc) >= 0.97, f"frame {i}"
        assert all((c == 0).all() for c in _corners(mask))
        black = rgb.max(axis=2) < 10
        assert (mask[black] > 0).mean() < 0.02, f"frame {i}: black border kept"
    mask, shape = fov_mask_for_sequence(laparoscopy, FovConfig())
    assert shape == "circle"
    assert _kept(mask, _inner_region(laparoscopy, level=30, erode_px=4)) >= 0.98


def test_phantom_without_border_is_kept_whole():
    frames = [_read_rgb(p) for p in _folder(LAPARO / "phantom_seq_png")]
    for i, rgb in enumerate(frames[::5]):
        mask, shape = fov_mask(rgb, FovConfig())
        assert shape in ("full", "rectangle"), f"frame {i}: {shape}"
        assert (mask > 0).mean() >= 0.98
    mask, shape = fov_mask_for_sequence(frames, FovConfig())
    assert shape in ("full", "rectangle") and (mask > 0).mean() >= 0.98


def _textured(h: int, w: int, seed: int = 0) -> np.ndarray:
    """Pink tissue-like texture: base colour, smooth noise, shading."""
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 3)
    noise *= 25 / noise.std()
    yy, xx = np.mgrid[0:h, 0:w]
    shade = 0.75 + 0.25 * np.cos(xx / w * np.pi - 0.5) * np.cos(yy / h * np.pi - 0.5)
    base = np.array([205, 115, 110], np.float32)
    img = (base[None, None] + noise[..., None] * np.array([1.0, 0.6, 0.6])) * shade[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


def test_synthetic_bright_image_is_full():
    mask, shape = fov_mask(_textured(256, 320), FovConfig())
    assert shape == "full" and (mask == 255).all()


OCTAGON = np.array([[90, 0], [210, 0], [299, 90], [299, 210], [210, 299], [90, 299],
                    [0, 210], [0, 90]], np.int32)  # fmt: skip


def _octagon_scope(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rgb = _textured(300, 300, seed)
    scope = np.zeros((300, 300), np.uint8)
    cv2.fillConvexPoly(scope, OCTAGON, 1)
    rgb[scope == 0] = 8
    return rgb, scope


def test_dark_lumen_in_the_middle_is_not_border():
    rgb, scope = _octagon_scope()
    cv2.circle(rgb, (170, 140), 45, (6, 4, 4), thickness=-1)  # lumen, as black as the border
    mask, shape = fov_mask(rgb, FovConfig())
    assert shape == "octagon"
    assert (mask[110:170, 140:200] == 255).all(), "lumen cut out"
    assert _kept(mask, cv2.erode(scope, np.ones((9, 9), np.uint8)) > 0) >= 0.99
    assert (mask[scope == 0] == 0).all()


def test_sequence_mask_recovers_corners_dark_in_single_frames():
    """In each frame a black lumen swallows one cut corner of the scope; a single frame's hull
    loses it, the sequence's mask does not."""
    frames, scope = [], None
    for k in range(8):
        rgb, scope = _octagon_scope(seed=k)
        a, b = OCTAGON[k], OCTAGON[(k + 1) % 8]
        centre = (int((a[0] + b[0]) / 2), int((a[1] + b[1]) / 2))
        cv2.circle(rgb, centre, 70, (5, 3, 3), thickness=-1)
        frames.append(rgb)
    core = cv2.erode(scope, np.ones((9, 9), np.uint8)) > 0
    assert min(_kept(fov_mask(f, FovConfig())[0], core) for f in frames) < 0.98
    mask, shape = fov_mask_for_sequence(frames, FovConfig())
    assert shape == "octagon"
    assert _kept(mask, core) >= 0.99 and (mask[scope == 0] == 0).all()


def test_synthetic_circle_and_rectangle():
    rgb = _textured(240, 320)
    disc = np.zeros((240, 320), np.uint8)
    cv2.circle(disc, (160, 120), 110, 1, thickness=-1)
    circled = rgb.copy()
    circled[disc == 0] = 0
    mask, shape = fov_mask(circled, FovConfig())
    assert shape == "circle"
    assert _kept(mask, cv2.erode(disc, np.ones((11, 11), np.uint8)) > 0) == 1.0
    assert (mask[disc == 0] == 0).all()
    barred = rgb.copy()
    barred[:, :40] = 0
    barred[:, -40:] = 0
    mask, shape = fov_mask(barred, FovConfig())
    assert shape == "rectangle"
    assert (mask[:, :40] == 0).all() and (mask[:, -40:] == 0).all()
    assert (mask[5:-5, 45:-45] == 255).all()


def test_disabled_fov_keeps_everything():
    mask, shape = fov_mask(np.zeros((20, 30, 3), np.uint8), FovConfig(enabled=False))
    assert shape == "full" and (mask == 255).all()


# Burned-in boxes in the Kvasir frames, measured by eye on the images: (rows, cols) of a patch
# inside each box and inside the scope's octagon. Black boxes (003, 005, 007, 008) and green
# boxes framed in black (001, 006). 009's green box is not framed and is not cut (a caveat).
KVASIR_BOXES = {
    "001.png": (slice(430, 540), slice(60, 200)),
    "003.png": (slice(430, 540), slice(60, 200)),
    "005.png": (slice(430, 540), slice(60, 200)),
    "006.png": (slice(430, 540), slice(60, 200)),
    "007.png": (slice(430, 540), slice(60, 200)),
    "008.png": (slice(500, 570), slice(100, 160)),
}


def test_kvasir_fov_ignores_text_and_cuts_boxes():
    for p in _folder(KVASIR):
        rgb = _read_rgb(p)
        mask, shape = fov_mask(rgb, FovConfig())
        assert shape == "octagon", p.name
        assert (mask[150:380, 250:550] == 255).all(), f"{p.name}: centre cut"
        assert (mask[:8, :8] == 0).all() and (mask[-8:, -8:] == 0).all(), p.name
        if p.name in KVASIR_BOXES:
            assert (mask[KVASIR_BOXES[p.name]] == 0).all(), f"{p.name}: overlay box kept"


# --- specular highlights ----------------------------------------------------------------------

# Saturated highlight pixels, the reference: all three channels >= 250, anywhere in the image
# (burned-in white text counts too; it is masked as well, which is what we want).
SATURATED = 250
NEAR_WHITE = 240


@pytest.fixture(scope="module")
def kvasir() -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
    out = []
    for p in _folder(KVASIR):
        rgb = _read_rgb(p)
        fov, _ = fov_mask(rgb, FovConfig())
        out.append((p.name, rgb, fov, specular_mask(rgb, SpecularConfig(), fov)))
    return out


def test_kvasir_highlights_covered_and_small(kvasir):
    hit = total = 0
    for name, rgb, fov, spec in kvasir:
        assert spec.dtype == np.uint8 and set(np.unique(spec)) <= {0, 255}
        area = (spec > 0).mean()
        assert area < 0.10, f"{name}: {area:.1%} of the image flagged"
        sat = rgb.min(axis=2) >= SATURATED
        hit += int((spec[sat] > 0).sum())
        total += int(sat.sum())
        if sat.sum() >= 20:  # a handful of pixels gives no meaningful fraction
            assert (spec[sat] > 0).mean() >= 0.90, f"{name}: saturated highlights missed"
        # Near-white: a looser level, counted inside the fov only (the rim of some scopes is a
        # bright line just outside it).
        near = (rgb.min(axis=2) >= NEAR_WHITE) & (fov > 0)
        if near.sum() >= 20:
            assert (spec[near] > 0).mean() >= 0.85, f"{name}: near-white highlights missed"
    assert hit / total >= 0.95


def test_kvasir_pale_diffuse_tissue_not_flagged(kvasir):
    """004's lower-left lobe is pale (V >= 230, S ~ 34) but diffuse: no highlight there."""
    rgb, spec = next((r, s) for n, r, _, s in kvasir if n == "004.png")
    y0, y1, x0, x1 = 440, 540, 150, 260
    hsv = cv2.cvtColor(rgb[y0:y1, x0:x1], cv2.COLOR_RGB2HSV)
    assert (hsv[..., 2] >= 230).mean() > 0.9  # the patch is indeed pale and bright
    assert (spec[y0:y1, x0:x1] > 0).mean() < 0.10


def _with_blobs(seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Textured pink image with elliptic highlights, half saturated white and half a dimmer
    off-white (only the relative test finds those), and one large pale diffuse patch."""
    h, w = 256, 320
    rgb = _textured(h, w, seed).astype(np.float32)
    yy, xx = np.mgrid[0:h, 0:w]
    pale = np.exp(-(((xx - 240) / 40.0) ** 2 + ((yy - 190) / 30.0) ** 2))[..., None]
    rgb = rgb * (1 - pale) + np.array([248, 215, 205], np.float32) * pale
    blobs = np.zeros((h, w), np.uint8)
    dim = np.zeros((h, w), np.uint8)
    rng = np.random.default_rng(seed)
    for i, (cx, cy) in enumerate( [(50, 50), (130, 40), (220, 60), (290, 40), (60, 150), (150, 130),
                   (40, 220), (120, 215), (180, 200), (280, 120)]):  # fmt: skip
        axes = (int(rng.integers(5, 14)), int(rng.integers(4, 10)))
        cv2.ellipse(
            dim if i % 2 else blobs, (cx, cy), axes, float(rng.uniform(0, 180)), 0, 360, 1, -1
        )
    rgb[blobs > 0] = 255
    rgb[dim > 0] = (236, 230, 226)
    blobs |= dim
    rgb = cv2.GaussianBlur(np.clip(rgb, 0, 255), (0, 0), 0.7)
    return rgb.astype(np.uint8), blobs > 0


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def test_synthetic_blobs_iou():
    rgb, blobs = _with_blobs()
    spec = specular_mask(rgb, SpecularConfig()) > 0
    assert _iou(spec, blobs) >= 0.6  # the default 2 px dilation is most of the difference
    assert spec[blobs].mean() >= 0.95
    found = specular_mask(rgb, SpecularConfig(dilate_px=0)) > 0  # detection alone
    assert _iou(found, blobs) >= 0.85


def test_specular_respects_fov_and_combine():
    rgb, blobs = _with_blobs()
    fov = np.zeros(rgb.shape[:2], np.uint8)
    fov[:, :160] = 255
    spec = specular_mask(rgb, SpecularConfig(), fov)
    assert (spec[:, 160:] == 0).all() and (spec[:, :150][blobs[:, :150]] > 0).mean() > 0.95
    out = combine(fov, spec)
    assert out.dtype == np.uint8 and set(np.unique(out)) == {0, 255}
    assert (out[:, 160:] == 0).all() and (out[spec > 0] == 0).all()
    assert (out[(fov > 0) & (spec == 0)] == 255).all()
    assert not specular_mask(rgb, SpecularConfig(enabled=False)).any()
