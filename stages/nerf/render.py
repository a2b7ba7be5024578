"""Use a trained model: save / load it, render depth (z), opacity and colour for any camera, and
evaluate density on a 3D grid (for marching cubes). World units in, world units out.

    model = load_model(folder)                    # 04_nerf/ (or the model.pt path)
    prior = load_prior(centerline / "prior.npz")
    out = render_image(model, prior, intrinsics, c2w)   # depth (H, W) z-depth, opacity, rgb
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from endopipe.pipeline.errors import ConfigError
from endopipe.stages.camera import Camera, pixel_rays
from endopipe.stages.nerf.bounds import scene_bounds
from endopipe.stages.nerf.config import NerfConfig
from endopipe.stages.nerf.files import MODEL_FILE
from endopipe.stages.nerf.model import NerfModel
from endopipe.stages.nerf.sampling import weight_quantiles
from endopipe.stages.nerf.scene import SceneBox


def save_model(path: Path, model: NerfModel, meta: dict | None = None) -> None:
    """model.pt: config, scene box, frame count, weights (CPU tensors), free-form meta."""
    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    blob = {
        "format": "endopipe-nerf/1",
        "config": model.cfg.model_dump(mode="json"),
        "box": model.box.state(),
        "n_frames": int(model.exposure.shape[0]),
        "state": state,
        "meta": meta or {},
    }
    tmp = Path(path).with_suffix(".tmp")
    torch.save(blob, tmp)
    tmp.replace(path)


def pick_device(name: str) -> torch.device:
    """The torch device a setting names: auto is CUDA when torch sees one, else the CPU; cuda
    without one is one line saying so (not a traceback deep in training)."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ConfigError(
            "device cuda: torch sees no CUDA device (a CPU build, or no driver); set the device "
            "to auto or cpu, or install the CUDA build of torch (make demo TORCH_SPEC=torch)"
        )
    return torch.device(name)


def load_model(folder: Path | str, device: str | torch.device = "cpu") -> NerfModel:
    """The trained model in a nerf stage folder (or a model.pt path), in eval mode."""
    path = Path(folder)
    if path.is_dir():
        path = path / MODEL_FILE
    blob = torch.load(path, map_location="cpu", weights_only=False)
    cfg = NerfConfig.model_validate(blob["config"])
    model = NerfModel(cfg, SceneBox.from_state(blob["box"]), blob["n_frames"])
    model.load_state_dict(blob["state"])
    model.meta = blob.get("meta", {})  # type: ignore[attr-defined]
    return model.to(device).eval()


def weight_median_and_spread(
    out: dict[str, torch.Tensor], far: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Each rendered ray's median depth (half its weight lies nearer; scene z-depth) and how
    far from one surface it is: the interquartile range of its weight over that median. A
    surface puts the weight in a thin shell (C3VD's far lumen: 4% of the depth, 8% at the
    90th percentile); haze in front of a wall or a ray grazing a fold's rim spreads it (rays
    through holes in C3VD's baked wall: up to 30%), and the expected depth there is a blend of
    the haze and the wall, nearer than either; the median stays with the heavier of the two."""
    q = weight_quantiles(out["t"], out["weights"], far, (0.25, 0.5, 0.75))
    return q[:, 1], (q[:, 2] - q[:, 0]) / q[:, 1].clamp_min(1e-9)


def weight_spread(out: dict[str, torch.Tensor], far: torch.Tensor) -> torch.Tensor:
    """The spread of `weight_median_and_spread` alone."""
    return weight_median_and_spread(out, far)[1]


def surface_found(
    opacity: np.ndarray, spread: np.ndarray, min_opacity: float, max_spread: float | None
) -> tuple[np.ndarray, np.ndarray]:
    """(found, hazy) of volume-rendered rays: those that get a depth (opaque enough, and their
    weight on one surface), and those left unknown for their spread alone (None: any)."""
    opaque = opacity >= min_opacity
    hazy = opaque & (spread > max_spread) if max_spread is not None else np.zeros_like(opaque)
    return opaque & ~hazy, hazy


@torch.no_grad()
def render_image(
    model: NerfModel,
    prior,
    intrinsics: Camera,
    c2w: np.ndarray,
    height: int | None = None,
    width: int | None = None,
    *,
    chunk: int | None = None,
    colour: bool = True,
    frame: int | None = None,
    light_c2w: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Render one camera (world c2w, OpenCV). Returns float32 arrays: depth (H, W), the
    expected z-depth in world units (0 where the ray stays transparent), median (H, W), the
    weights' median z-depth (0 there too), opacity (H, W), spread (H, W; see
    `weight_median_and_spread`), and rgb (H, W, 3) in [0, 1] (display-encoded) when `colour`.
    `frame` picks a training frame's exposure. `light_c2w`: the camera (world c2w) that
    carries the scope's light when the rendered one does not (a rectified rig's right eye is lit
    from the left eye); None: the light at the rendered camera's centre."""
    h = height or intrinsics.height
    w = width or intrinsics.width
    k = intrinsics if (w, h) == (intrinsics.width, intrinsics.height) else intrinsics.scaled(w, h)
    dev = model.log_gain.device
    c2w_s = torch.as_tensor(
        model.box.c2w_to_scene(np.asarray(c2w)), dtype=torch.float32, device=dev
    )
    vv, uu = torch.meshgrid(
        torch.arange(h, device=dev, dtype=torch.float32),
        torch.arange(w, device=dev, dtype=torch.float32),
        indexing="ij",
    )
    o, d = pixel_rays(k, c2w_s, uu.reshape(-1), vv.reshape(-1))
    light = None
    if light_c2w is not None:
        scene = model.box.c2w_to_scene(np.asarray(light_c2w))
        light = torch.as_tensor(scene, dtype=torch.float32, device=dev)
    chunk = chunk or model.cfg.sampling.chunk
    depth, median, spread, opacity, rgb = [], [], [], [], []
    fr = None if frame is None else torch.tensor([frame], device=dev)
    for a in range(0, o.shape[0], chunk):
        oc, dc = o[a : a + chunk], d[a : a + chunk]
        near, far = scene_bounds(model, prior, oc, dc)
        out = model.render_rays(
            oc,
            dc,
            near,
            far,
            colour=colour,
            frame=None if fr is None else fr.expand(len(oc)),
            light=light,
        )
        depth.append(out["depth"])
        mid, spread_of = weight_median_and_spread(out, far)
        median.append(mid)
        spread.append(spread_of)
        opacity.append(out["opacity"])
        if colour:
            rgb.append(out["rgb"].clamp(0, 1))
    op = torch.cat(opacity).view(h, w)
    z = torch.cat(depth).view(h, w) * model.box.scale
    z = torch.where(op > 1e-3, z, torch.zeros_like(z))
    zm = torch.cat(median).view(h, w) * model.box.scale
    zm = torch.where(op > 1e-3, zm, torch.zeros_like(zm))
    result = {
        "depth": z.float().cpu().numpy(),
        "median": zm.float().cpu().numpy(),
        "spread": torch.cat(spread).view(h, w).float().cpu().numpy(),
        "opacity": op.float().cpu().numpy(),
    }
    if colour:
        result["rgb"] = torch.cat(rgb).view(h, w, 3).float().cpu().numpy()
    return result


@dataclass
class DensityGrid:
    """sigma on a regular world-frame grid: values[i, j, k] at origin + (i, j, k) * spacing.

    sigma is per world unit (optical thickness of a step ds is sigma * ds)."""

    values: np.ndarray
    origin: np.ndarray
    spacing: float

    def points(self) -> np.ndarray:
        axes = [self.origin[i] + self.spacing * np.arange(self.values.shape[i]) for i in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), -1)


@torch.no_grad()
def density_grid(
    model: NerfModel,
    resolution: int = 256,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
    chunk: int = 1 << 18,
) -> DensityGrid:
    """Density on a world-axis-aligned grid with `resolution` nodes along its longest side,
    over `bounds` (world lo, hi) or the world bounding box of the model's scene box."""
    box = model.box
    if bounds is None:
        corners = np.array(np.meshgrid(*zip(box.lo, box.hi, strict=True), indexing="ij"))
        corners = box.scene_to_world_np(corners.reshape(3, -1).T)
        lo, hi = corners.min(0), corners.max(0)
    else:
        lo, hi = (np.asarray(b, np.float64) for b in bounds)
    spacing = float((hi - lo).max() / max(resolution - 1, 1))
    shape = tuple(int(np.floor((hi[i] - lo[i]) / spacing)) + 1 for i in range(3))
    dev = model.log_gain.device
    axes = [
        torch.as_tensor(lo[i] + spacing * np.arange(shape[i]), dtype=torch.float32)
        for i in range(3)
    ]
    out = np.empty(shape, np.float32)
    plane = shape[1] * shape[2]
    yz = torch.stack(torch.meshgrid(axes[1], axes[2], indexing="ij"), -1).reshape(-1, 2)
    step = max(1, chunk // plane)
    for i0 in range(0, shape[0], step):
        xs = axes[0][i0 : i0 + step]
        pts = torch.cat([xs.repeat_interleave(plane)[:, None], yz.repeat(len(xs), 1)], 1).to(dev)
        sigma = model.density_scene(box.world_to_scene(pts)) / box.scale
        out[i0 : i0 + len(xs)] = sigma.view(len(xs), shape[1], shape[2]).cpu().numpy()
    return DensityGrid(values=out, origin=lo, spacing=spacing)


@torch.no_grad()
def surface_density_level(
    model: NerfModel,
    prior,
    intrinsics: Camera,
    c2ws: list[np.ndarray],
    rays: int = 4096,
    seed: int = 0,
    cameras: int = 10,
) -> float | None:
    """The density (per world unit) at which an iso-surface of the field passes through the
    volume renderer's surface: the median, over random pixel rays of about `cameras` of the
    given cameras (evenly spread), of the density at each ray's median depth (where its
    transmittance falls to one half). A fixed
    iso-level sits wherever the field's ramp in front of the wall crosses it (measured 4% in
    front of the rendered depth on a synthetic colon); this one follows the field. None when
    no ray becomes opaque."""
    if model.field.is_sdf:  # the zero level, exactly: sigma = 1 / (2 beta) there
        return float(0.5 / model.field.beta / model.box.scale)
    if not c2ws:
        return None
    c2ws = c2ws[:: max(1, len(c2ws) // cameras)]
    dev = model.log_gain.device
    gen = np.random.default_rng(seed)
    k = intrinsics
    per_cam = max(1, rays // len(c2ws))
    levels = []
    for c2w in c2ws:
        c2w_s = torch.as_tensor(
            model.box.c2w_to_scene(np.asarray(c2w)), dtype=torch.float32, device=dev
        )
        u = torch.as_tensor(gen.uniform(0, k.width - 1, per_cam), dtype=torch.float32, device=dev)
        v = torch.as_tensor(gen.uniform(0, k.height - 1, per_cam), dtype=torch.float32, device=dev)
        o, d = pixel_rays(k, c2w_s, u, v)
        near, far = scene_bounds(model, prior, o, d)
        out = model.render_rays(o, d, near, far, colour=False, normals=False)
        w, t, op = out["weights"], out["t"], out["opacity"]
        keep = op > 0.9
        if not keep.any():
            continue
        cw = torch.cumsum(w[keep], 1)
        last = t.shape[1] - 1
        idx = (cw < 0.5).sum(1).clamp(max=last)
        tm = t[keep].gather(1, idx[:, None])
        x = o[keep] + tm * d[keep]
        levels.append(model.density_scene(x) / model.box.scale)
    if not levels:
        return None
    return float(torch.cat(levels).median())
