"""Training data: frames, masks and poses in the scene frame; rays; batches of rays and patches."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from endopipe.stages.camera import Camera, direction_table, pixel_rays

if TYPE_CHECKING:
    from endopipe.stages.nerf.pose_refine import PoseCorrection


def holdout_split(indices: list[int], every: int) -> tuple[list[int], list[int]]:
    """(train, held out): a frame is held out when its endopipe index % every == 0."""
    if every <= 0:
        return list(indices), []
    held = [i for i in indices if i % every == 0]
    train = [i for i in indices if i % every != 0]
    if not train:  # too few frames to hold any out
        return list(indices), []
    return train, held


@dataclass
class Batch:
    frame: torch.Tensor  # (B,) position in FrameSet
    u: torch.Tensor  # (B,) float pixel x
    v: torch.Tensor  # (B,) float pixel y
    rgb: torch.Tensor  # (B, 3) display-encoded target in [0, 1]
    valid: torch.Tensor  # (B,) bool: usable for the photometric loss
    n_patches: int  # the first n_patches * p * p rays are patches, row-major p x p each
    patch: int


class FrameSet:
    """Frames of one sequence on a device: images, masks, scene-frame poses, the camera (at the
    images' resolution)."""

    def __init__(
        self,
        images: np.ndarray,
        masks: np.ndarray,
        c2w_scene: np.ndarray,
        camera: Camera,
        ids: list[int],
        device: torch.device,
    ) -> None:
        self.images = torch.as_tensor(images, dtype=torch.float32, device=device)  # (F,H,W,3)
        self.masks = torch.as_tensor(masks, dtype=torch.bool, device=device)  # (F,H,W)
        self.c2w = torch.as_tensor(c2w_scene, dtype=torch.float32, device=device)  # (F,4,4)
        self.camera = camera
        self.ids = list(ids)
        self.device = device
        self.n, self.h, self.w = self.masks.shape
        if (camera.width, camera.height) != (self.w, self.h):
            raise ValueError(
                f"camera is {camera.width}x{camera.height}, frames are {self.w}x{self.h}"
            )
        self._directions = direction_table(camera, device)  # distorted lenses only
        # Learnt pose corrections (pose_refine.py), applied while `refining`; None: poses as given.
        self.correction: PoseCorrection | None = None
        self.refining = False

    def pose(self, frame: torch.Tensor) -> torch.Tensor:
        """Scene-frame c2w of frames ((B,) -> (B, 4, 4)): the given pose, corrected while
        refining (with gradients to the corrections)."""
        if self.correction is None or not self.refining:
            return self.c2w[frame]
        return self.correction.apply(self.c2w)[frame]

    def rays(self, frame: torch.Tensor, u: torch.Tensor, v: torch.Tensor):
        """Scene-frame rays (origins, directions with camera z = 1) through pixels of frames."""
        return self.pixel_rays(self.pose(frame), u, v)

    def pixel_rays(self, c2w: torch.Tensor, u: torch.Tensor, v: torch.Tensor):
        """Rays of this camera at scene-frame poses c2w ((4, 4) or (B, 4, 4))."""
        return pixel_rays(self.camera, c2w, u, v, self._directions)


class RaySampler:
    """Random rays of the training frames: single pixels and p x p patches (for L_smooth, the
    normal variance and L_geo), all inside the usable mask (patch pixels may leave it).

    `frames_per_step` > 0: each batch is drawn from that many training frames chosen at random
    (every pixel of theirs alike), so a timed field reads its lines sliced at a few times
    (`VMTimeGrid.slice_up_to`); 0: each ray from any training frame."""

    def __init__(
        self,
        frames: FrameSet,
        train: list[int],
        batch: int,
        patch: int,
        patch_fraction: float,
        gen: torch.Generator,
        frames_per_step: int = 0,
    ) -> None:
        self.f = frames
        self.train = torch.as_tensor(train, dtype=torch.long, device=frames.device)
        self.batch, self.patch = batch, patch
        self.frames_per_step = min(int(frames_per_step), len(train))
        self.n_patches = int(round(batch * patch_fraction / (patch * patch)))
        self.n_single = batch - self.n_patches * patch * patch
        self.gen = gen
        m = frames.masks[self.train].reshape(len(train), -1)
        pos = torch.nonzero(m)
        self.valid_frame = self.train[pos[:, 0]].to(torch.int32)
        self.valid_pix = pos[:, 1].to(torch.int32)
        # Patch corners: usable pixels that leave room for the patch.
        hh, ww = frames.h - patch + 1, frames.w - patch + 1
        corner = frames.masks[self.train][:, :hh, :ww].reshape(len(train), -1)
        cpos = torch.nonzero(corner)
        self.corner_frame = self.train[cpos[:, 0]].to(torch.int32)
        self.corner_pix = cpos[:, 1].to(torch.int32)
        self.corner_w = ww
        if len(self.valid_pix) == 0:
            raise ValueError("no usable pixels in the training frames (masks are all 0)")
        # Where each training frame's pixels and corners lie in the lists above (frame-major).
        self.valid_span = _spans(pos[:, 0], len(train))
        self.corner_span = _spans(cpos[:, 0], len(train))
        self.usable_frames = torch.nonzero(self.valid_span[1] > 0)[:, 0]

    def _draw(self, n: int, total: int, spans, chosen) -> torch.Tensor:
        """n random entries of a frame-major list: any entry, or one of the chosen frames'
        (each of them about as often, every entry of a frame alike)."""
        dev, g = self.f.device, self.gen
        if chosen is None:
            return torch.randint(total, (n,), generator=g, device=dev)
        start, count = spans
        slot = chosen[torch.randint(len(chosen), (n,), generator=g, device=dev)]
        u = torch.rand(n, generator=g, device=dev)
        return start[slot] + (u * count[slot]).long().minimum(count[slot] - 1)

    def _chosen_frames(self) -> torch.Tensor | None:
        """This batch's training frames (positions in `train` with usable pixels), or None."""
        if self.frames_per_step <= 0:
            return None
        usable = self.usable_frames
        pick = torch.randperm(len(usable), generator=self.gen, device=self.f.device)
        return usable[pick[: self.frames_per_step]]

    def sample(self) -> Batch:
        dev = self.f.device
        frames, us, vs = [], [], []
        chosen = self._chosen_frames()
        corners = chosen
        if chosen is not None:  # the chosen frames with room for a patch
            corners = chosen[self.corner_span[1][chosen] > 0]
        if self.n_patches and len(self.corner_pix) and (corners is None or len(corners)):
            k = self._draw(self.n_patches, len(self.corner_pix), self.corner_span, corners)
            fr = self.corner_frame[k].long()
            pix = self.corner_pix[k].long()
            v0, u0 = pix // self.corner_w, pix % self.corner_w
            dv, du = torch.meshgrid(
                torch.arange(self.patch, device=dev),
                torch.arange(self.patch, device=dev),
                indexing="ij",
            )
            frames.append(fr[:, None].expand(-1, self.patch**2).reshape(-1))
            vs.append((v0[:, None] + dv.reshape(1, -1)).reshape(-1))
            us.append((u0[:, None] + du.reshape(1, -1)).reshape(-1))
            n_patches = self.n_patches
        else:
            n_patches = 0
        n_single = self.batch - n_patches * self.patch**2
        k = self._draw(n_single, len(self.valid_pix), self.valid_span, chosen)
        frames.append(self.valid_frame[k].long())
        pix = self.valid_pix[k].long()
        vs.append(pix // self.f.w)
        us.append(pix % self.f.w)
        fr, u, v = torch.cat(frames), torch.cat(us), torch.cat(vs)
        return Batch(
            frame=fr,
            u=u.float(),
            v=v.float(),
            rgb=self.f.images[fr, v, u],
            valid=self.f.masks[fr, v, u],
            n_patches=n_patches,
            patch=self.patch,
        )


def _spans(frame_of: torch.Tensor, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(start, count) of each of n frames in a frame-major list whose entries' frames (0..n-1,
    sorted) are `frame_of`."""
    count = torch.bincount(frame_of, minlength=n)
    return torch.cumsum(count, 0) - count, count


def neighbours(train: list[int]) -> dict[int, int]:
    """For L_geo: each training frame's next training frame (the last one: its previous)."""
    order = sorted(train)
    out = {}
    for k, i in enumerate(order):
        if len(order) < 2:
            break
        out[i] = order[k + 1] if k + 1 < len(order) else order[k - 1]
    return out
