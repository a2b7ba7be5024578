"""Ray bounds: where along each ray the samplers look (nerfacc's estimators). From the lumen
prior (the tube's wall, capped at a few radii) or, as an ablation and without a prior, from the
scene box. Training and inference share them, so this sits beside sampling, not in train.py."""

from __future__ import annotations

import torch

from endopipe.stages.nerf.config import NerfConfig
from endopipe.stages.nerf.model import NerfModel
from endopipe.stages.nerf.scene import SceneBox


class PriorBounds:
    """The lumen prior seen from the scene frame: ray bounds in scene depth, core membership."""

    def __init__(self, prior, box: SceneBox, cfg: NerfConfig) -> None:
        self.prior, self.box, self.cfg = prior, box, cfg
        self.max_far = cfg.sampling.far_radii * float(prior.typical_radius)
        # Sampling looks past the wall far enough to reach the points the cameras saw.
        self.margin = max(cfg.sampling.bounds_margin, float(prior.margin))

    def _world_rays(self, o: torch.Tensor, d: torch.Tensor):
        rot = torch.as_tensor(self.box.rotation, dtype=d.dtype, device=d.device)
        return self.box.scene_to_world(o), (d @ rot.T) * self.box.scale

    def bounds(
        self,
        o: torch.Tensor,
        d: torch.Tensor,
        margin: float,
        wall: bool = False,
        past_points: bool | None = None,
    ):
        """near, far (scene z-depth) and whether far is the wall (not the cap). With
        sampling.bounds = "box" (an ablation) the sampling bounds come from the scene box;
        `wall=True` always asks the prior. `past_points` (default: not `wall`): far reaches
        the farthest SfM points behind the wall of a prior they contradict."""
        if self.cfg.sampling.bounds == "box" and not wall:
            near, far = self.box.ray_bounds(o, d, self.cfg.sampling.near_fraction)
            return near, far, torch.zeros_like(near, dtype=torch.bool)
        ow, dw = self._world_rays(o, d)
        near, far = self.prior.ray_bounds(
            ow, dw, margin, max_far=self.max_far, near_fraction=self.cfg.sampling.near_fraction
        )
        near, far = near.to(o.dtype), far.to(o.dtype)
        if self.prior.kind == "none":  # no wall: far is the reach of the SfM points
            return near, torch.maximum(far, near * 1.5), torch.zeros_like(near, dtype=torch.bool)
        cap = self.max_far / dw.norm(dim=-1)
        if self.cfg.sampling.open_tube_ends and self.prior.kind == "tube":
            far = torch.where(self._past_ends(ow, dw, far), cap.to(far.dtype), far)
        is_wall = far < 0.999 * cap
        reach = self.prior.reach
        if past_points is None:
            past_points = not wall
        if reach and past_points and self.prior.unit is not None:
            # A forced prior the SfM points contradict (it carries the fitting shape's unit):
            # its wall ends rays the scene goes on past (the cavity preset's ellipsoid on a
            # colon), so sampling reaches past every point the cameras saw. Not for a prior
            # that fits: on the bench colon (tube) it cost 2.3x the training time and Chamfer
            # 4.90% against 4.57%, on the bench cavity (ellipsoid) 4.36% against 3.19%.
            far = torch.maximum(far, (reach / dw.norm(dim=-1)).to(far.dtype))
        return near, torch.maximum(far, near * 1.5), is_wall

    def _past_ends(self, ow: torch.Tensor, dw: torch.Tensor, far: torch.Tensor) -> torch.Tensor:
        """Rays whose far point lies past an end of the tube's centerline: there the wall is the
        last segment continued straight, a guess (on the bench colon every ray down the lumen
        left it 50-130 units past the 82-unit curve's end, and the far lumen came out 10-40%
        short)."""
        s = self.prior.nearest_param(torch.addcmul(ow, far[:, None].to(ow.dtype), dw))
        return (s < 0) | (s > self.prior.length)

    def typical_distance(self) -> float | None:
        """Without a wall, the median camera-to-point distance (scene units), else None."""
        depth = getattr(self.prior, "depth", None)
        return None if depth is None else float(depth) / self.box.scale

    def in_core(self, x: torch.Tensor, fraction: float) -> torch.Tensor:
        return self.prior.in_core(self.box.scene_to_world(x), fraction)


class PixelBounds:
    """`PriorBounds` of every pixel of the training frames, worked out once: a training step's
    rays go through whole pixels of cameras that do not move (no pose refinement), and the
    prior's ray march is small-tensor work that cost 13 ms of a 110 ms step at 1,024 rays.
    Holds near, far (sampling, with the margin) and the wall's depth with its flag."""

    def __init__(self, pb: PriorBounds, frames, train: list[int]) -> None:
        h, w, dev = frames.h, frames.w, frames.device
        vv, uu = torch.meshgrid(
            torch.arange(h, device=dev), torch.arange(w, device=dev), indexing="ij"
        )
        u, v = uu.reshape(-1).float(), vv.reshape(-1).float()
        self.row = torch.full((frames.n,), -1, dtype=torch.long, device=dev)
        self.row[torch.as_tensor(train, device=dev)] = torch.arange(len(train), device=dev)
        self.w = w
        near, far, wall, has = [], [], [], []
        for f in train:
            o, d = frames.rays(torch.full_like(u, f, dtype=torch.long), u, v)
            n_, f_, _ = pb.bounds(o, d, pb.margin)
            _, w_, h_ = pb.bounds(o, d, 0.0, wall=True)
            near.append(n_), far.append(f_), wall.append(w_), has.append(h_)
        self.near, self.far = torch.stack(near), torch.stack(far)
        self.wall, self.has_wall = torch.stack(wall), torch.stack(has)

    def _at(self, table: torch.Tensor, frame, u, v) -> torch.Tensor:
        return table[self.row[frame], v.long() * self.w + u.long()]

    def sampling(self, frame, u, v) -> tuple[torch.Tensor, torch.Tensor]:
        """near, far of the pixels (frame, u, v), as `PriorBounds.bounds(o, d, margin)`."""
        return self._at(self.near, frame, u, v), self._at(self.far, frame, u, v)

    def wall_of(self, frame, u, v) -> tuple[torch.Tensor, torch.Tensor]:
        """The wall's depth and whether there is one, as `bounds(o, d, 0, wall=True)`."""
        return self._at(self.wall, frame, u, v), self._at(self.has_wall, frame, u, v)


def target_bounds(pb: PriorBounds, frames, targets, chunk: int = 65_536):
    """`PriorBounds.bounds(o, d, margin)` of each ray of `targets` (a SparseDepth: frame, u, v),
    worked out once, as `PixelBounds` for the pixels: the SfM points' rays are the same at
    every step while the poses stay as given (their march cost 10 s of C3VD's training)."""
    near, far = [], []
    for a in range(0, len(targets), chunk):
        rows = slice(a, a + chunk)
        o, d = frames.rays(targets.frame[rows], targets.u[rows], targets.v[rows])
        n_, f_, _ = pb.bounds(o, d, pb.margin)
        near.append(n_), far.append(f_)
    return torch.cat(near), torch.cat(far)


def scene_bounds(model: NerfModel, prior, o: torch.Tensor, d: torch.Tensor):
    """near / far (scene depth) of scene-frame rays: from the prior, else from the box."""
    if prior is None:
        return model.box.ray_bounds(o, d, model.cfg.sampling.near_fraction)
    pb = PriorBounds(prior, model.box, model.cfg)
    near, far, _ = pb.bounds(o, d, pb.margin)
    return near, far
