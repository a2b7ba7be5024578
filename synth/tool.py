"""A grasping tool in view: a grey metallic shaft with two jaws, as an exact analytic occluder.

The tool is a union of capsules (a segment swept by a ball): the 5 mm shaft from its port
(beside and behind the camera, so the shaft enters the image from an edge) to the jaws' hinge,
and two thin jaws from the hinge to either side of the tip. Rays meet capsules in closed form,
so the tool's depth is as exact as the wall's; the frame's depth is whatever the ray meets
first. The tip comes in from the port over the first part of the clip, reaches the pulled spot
and then moves with it (`deform.Pull`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from endopipe.stages.camera import Camera
from endopipe.synth.deform import BUMP_SLOPE, Pull
from endopipe.synth.raycast import StepBound, camera_rays, trace
from endopipe.synth.render import LUMA, Lighting
from endopipe.synth.scene import Scene

SHAFT_RADIUS = 2.5  # mm: a 5 mm laparoscopic instrument
JAW_RADIUS = 0.9
JAW_LENGTH = 7.0  # mm, hinge to tip
JAW_SPREAD = 1.6  # mm, each jaw tip off the tool's axis
APPROACH = 35.0  # mm the tip travels in along the shaft before it grasps
#: Port of the shaft in the first camera's frame (mm): right, up and a little behind it.
PORT_CAMERA = np.array([32.0, -18.0, -8.0])
ALBEDO = np.array([0.42, 0.43, 0.45])  # linear, a hint of blue: brushed steel, low saturation
DIFFUSE = 0.2
SPECULAR = 1.2
SHININESS = 40.0


@dataclass(frozen=True)
class Capsule:
    a: np.ndarray  # (3,) segment start
    b: np.ndarray  # (3,) segment end
    radius: float


@dataclass
class ToolHit:
    """Where the tool covers a frame: per pixel t along the ray (inf: no tool), and the unit
    normal there."""

    t: np.ndarray  # (N,) float64
    normals: np.ndarray  # (N, 3)


class Tool:
    """The tool's path over the clip: fixed port, tip on the pulled spot once it grasps."""

    def __init__(self, pull: Pull, port: np.ndarray, view_dir: np.ndarray) -> None:
        self.pull = pull
        self.port = np.asarray(port, np.float64)
        self.view_dir = np.asarray(view_dir, np.float64)

    def tip(self, t: float) -> np.ndarray:
        """The jaws' tip: on the pulled spot from `pull.start`, coming in before that."""
        spot = self.pull.moved(t)
        if t >= self.pull.start:
            return spot
        back = self.port - spot
        back /= np.linalg.norm(back)
        u = t / self.pull.start if self.pull.start > 0 else 1.0
        ease = 0.5 - 0.5 * np.cos(np.pi * u)  # 0 -> 1, slow at both ends
        return spot + (1.0 - ease) * APPROACH * back

    def capsules(self, t: float) -> list[Capsule]:
        tip = self.tip(t)
        axis = tip - self.port
        axis /= np.linalg.norm(axis)
        hinge = tip - JAW_LENGTH * axis
        side = np.cross(axis, self.view_dir)
        side /= max(np.linalg.norm(side), 1e-9)
        return [
            Capsule(self.port, hinge, SHAFT_RADIUS),
            Capsule(hinge, tip + JAW_SPREAD * side, JAW_RADIUS),
            Capsule(hinge, tip - JAW_SPREAD * side, JAW_RADIUS),
        ]

    def cast(self, origin: np.ndarray, dirs: np.ndarray, t: float) -> ToolHit:
        """The nearest capsule along each unit ray from `origin`."""
        best = np.full(len(dirs), np.inf)
        normals = np.zeros_like(dirs)
        for cap in self.capsules(t):
            hit = capsule_hits(origin, dirs, cap)
            nearer = hit < best
            if not nearer.any():
                continue
            best = np.where(nearer, hit, best)
            p = origin + hit[nearer, None] * dirs[nearer]
            normals[nearer] = capsule_normals(p, cap)
        return ToolHit(best, normals)

    def describe(self) -> dict:
        return {
            "shaft_radius_mm": SHAFT_RADIUS,
            "jaw_length_mm": JAW_LENGTH,
            "port": self.port.tolist(),
            "approach_mm": APPROACH,
            "arrives_s": self.pull.start,
            "mask": "masks/NNNNNN.png: 255 = tool, 0 = tissue",
        }


def capsule_hits(origin: np.ndarray, dirs: np.ndarray, cap: Capsule) -> np.ndarray:
    """Distance along unit rays from one origin to a capsule's surface (inf: missed), the
    closed form of the segment's cylinder then its two end balls."""
    ba = cap.b - cap.a
    oa = origin - cap.a
    baba = float(ba @ ba)
    bard = dirs @ ba
    baoa = float(ba @ oa)
    rdoa = dirs @ oa
    oaoa = float(oa @ oa)
    r2 = cap.radius**2
    qa = baba - bard * bard
    qb = baba * rdoa - baoa * bard
    qc = baba * oaoa - baoa * baoa - r2 * baba
    h = qb * qb - qa * qc
    out = np.full(len(dirs), np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        t_side = (-qb - np.sqrt(h)) / qa
        y = baoa + t_side * bard
        side = (h >= 0) & (qa > 1e-12) & (y > 0) & (y < baba) & (t_side > 0)
        out[side] = t_side[side]
        for end in (cap.a, cap.b):
            oc = origin - end
            b = dirs @ oc
            hb = b * b - (float(oc @ oc) - r2)
            t_ball = -b - np.sqrt(hb)
            ok = (hb >= 0) & (t_ball > 0) & ~side
            out = np.where(ok & (t_ball < out), t_ball, out)
    return out


def capsule_normals(p: np.ndarray, cap: Capsule) -> np.ndarray:
    """Outward unit normals at points on a capsule: away from the nearest axis point."""
    ba = cap.b - cap.a
    s = np.clip((p - cap.a) @ ba / float(ba @ ba), 0.0, 1.0)
    n = p - (cap.a + s[:, None] * ba)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def shade_tool(
    hit: ToolHit,
    dirs: np.ndarray,
    light: Lighting,
    noise_std: float,
    rng: np.random.Generator,
    gain: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Linear-to-8-bit colours of the covered rays (M, 3 uint8) and where their specular
    reflection dominates (M,): steel lit by the light at the camera (broad highlights).
    `gain` (M,): the vignetting of the covered pixels."""
    covered = np.isfinite(hit.t)
    n = hit.normals[covered]
    cos = np.clip(-np.einsum("ij,ij->i", n, dirs[covered]), 0.0, 1.0)
    inv_r2 = 1.0 / hit.t[covered] ** 2
    diffuse = DIFFUSE * ALBEDO * (cos * inv_r2)[:, None]
    spec = SPECULAR * cos**SHININESS * inv_r2
    lin = light.exposure * (diffuse + spec[:, None]) + light.ambient * ALBEDO
    if gain is not None:
        lin = lin * gain[:, None]
    dominant = (light.exposure * spec > light.exposure * (diffuse * LUMA).sum(axis=1)) & (
        light.exposure * spec > 0.15
    )
    img = np.clip(lin, 0.0, 1.0) ** (1.0 / light.gamma)
    img = img + rng.normal(0.0, noise_std, img.shape)
    return np.round(np.clip(img, 0.0, 1.0) * 255.0).astype(np.uint8), dominant


#: Pixel (as fractions of width and height) whose ray picks the pulled spot at rest: a little
#: left of and below the centre, so the shaft from the upper right crosses much of the image.
SPOT_PIXEL = (0.42, 0.58)


def plan_pull(
    scene: Scene,
    bound: StepBound,
    intr: Camera,
    c2w: np.ndarray,
    amplitude: float,
    clip_s: float,
) -> tuple[Pull, Tool]:
    """The grasp seen from the first camera: the wall point at SPOT_PIXEL is pulled towards
    the tool's port (the tool draws it back along its shaft). The patch is wide enough that
    the pull stays gentle (Lipschitz <= 0.4); the tool comes in over the first fifth of the
    clip, then the pull grows and releases over the rest."""
    u, v = int(SPOT_PIXEL[0] * intr.width), int(SPOT_PIXEL[1] * intr.height)
    origin, dirs, _ = camera_rays(intr, c2w)
    ray = dirs[v * intr.width + u]
    t_hit = trace(scene, bound, origin, ray[None])[0][0]
    if not np.isfinite(t_hit):
        raise RuntimeError("synthetic pull: the first camera sees no wall at the pulled spot")
    spot = origin + t_hit * ray
    port = origin + c2w[:3, :3] @ PORT_CAMERA
    for _ in range(20):  # keep the port in the lumen (a narrow colon): pull it in towards the eye
        if scene.f_points(port[None])[0] < -2.0 * SHAFT_RADIUS:
            break
        port = origin + 0.8 * (port - origin)
    radius = max(12.0, amplitude * BUMP_SLOPE / 0.4)
    pull = Pull(spot, port - spot, amplitude, radius, start=0.2 * clip_s, end=clip_s)
    return pull, Tool(pull, port, c2w[:3, 2])
