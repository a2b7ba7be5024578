"""A synthetic endoscopy case with exact ground truth, written as an endopipe case folder
(docs/formats.md).

A seeded implicit anatomy (colon or cavity) is ray-cast exactly from a seeded camera path with a
light at the camera; the case gets the video, lossless frames, intrinsics, z-depth, poses, mesh,
specular masks and centre line. Units are millimetres throughout. The camera may have a distorted
lens and vignetting (`lens.py`): each pixel's ray is its undistorted direction, so the depth
stays exact on the frames' own pixel grid.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from endopipe.stages.camera import Camera
from endopipe.synth.events import Events, plan_events, spoil
from endopipe.synth.lens import LENSES, LensName, lens_camera, vignetting_gain
from endopipe.synth.raycast import FrameGeometry, MeshGuide, StepBound, trace, trace_frame
from endopipe.synth.render import Lighting, calibrate_exposure, shade
from endopipe.synth.scene import CavityScene, ColonScene, Scene
from endopipe.synth.texture import MucosaTexture
from endopipe.synth.trajectory import cavity_poses, colon_poses
from endopipe.synth.writer import CaseWriter

__all__ = ["SynthConfig", "SynthSummary", "generate_case"]

GUIDE_RAYS = 800_000  # above this many pixels in total, rays are guided by the wall's mesh


class SynthConfig(BaseModel):
    """What to generate; the same config always gives the same case, byte for byte."""

    model_config = ConfigDict(extra="forbid")

    seed: int = Field(0, description="Seed of the anatomy, texture, camera path and sensor noise.")
    frames: int = Field(60, ge=2, description="Number of frames (camera travels ~1 mm per frame).")
    step_mm: float = Field(
        1.0,
        gt=0.0,
        le=5.0,
        description="Mean camera travel per frame, mm (+-25% slowly varying); a colonoscope "
        "withdrawn at 25 fps moves about 0.3.",
    )
    pauses: int = Field(
        0, ge=0, description="Times the camera stands still during the recording (recordings)."
    )
    pause_frames: int = Field(25, ge=1, description="Frames each pause lasts (25: 1 s at 25 fps).")
    blurred: float = Field(
        0.0, ge=0.0, le=0.5, description="Fraction of frames smeared by motion blur."
    )
    washed_out: float = Field(
        0.0, ge=0.0, le=0.5, description="Fraction of frames washed out by the light."
    )
    fps: int = Field(15, ge=1, le=120, description="Frame rate of video.mp4.")
    width: int = Field(320, ge=16, description="Image width in pixels (even, for yuv420p video).")
    height: int = Field(256, ge=16, description="Image height in pixels (even).")
    shape: Literal["colon", "cavity"] = Field(
        "colon", description="colon: haustrated tube, camera advancing; cavity: stomach-like sac."
    )
    texture_contrast: float = Field(
        1.0, ge=0.0, le=3.0, description="Scales all texture contrast (<1: harder for SfM)."
    )
    fov_deg: float = Field(90.0, gt=10.0, lt=170.0, description="Horizontal field of view, deg.")
    noise_std: float = Field(
        0.01, ge=0.0, le=0.5, description="Gaussian sensor noise std on 0..1 intensities."
    )
    specular: bool = Field(True, description="Add Blinn-Phong highlights of the camera's light.")
    lens: LensName = Field(
        "pinhole",
        description="pinhole; barrel: OpenCV k1 -0.3, k2 0.06 (110 deg diagonal); fisheye: "
        "OpenCV equidistant k1 -0.05, k2 0.01 (140 deg diagonal).",
    )
    fov_diag_deg: float | None = Field(
        None,
        gt=10.0,
        lt=179.0,
        description="Field of view across the image diagonal, deg; replaces fov_deg "
        "(default: the lens's own; a pinhole keeps fov_deg).",
    )
    vignetting: float = Field(
        0.0,
        ge=0.0,
        lt=1.0,
        description="S of the linear gain 1 - S (r / r_corner)^2: corners get 1 - S of the light.",
    )

    @field_validator("width", "height")
    @classmethod
    def _even(cls, v: int) -> int:
        if v % 2:
            raise ValueError("must be even (H.264 yuv420p)")
        return v


class SynthSummary(BaseModel):
    """What was generated, for the CLI to print."""

    out: str = Field(description="The case folder.")
    frames: int = Field(description="Frames written.")
    path_length_mm: float = Field(description="Length of the camera path (sum of frame steps).")
    mean_radius_mm: float = Field(description="Mean lumen radius along gt/centerline.json.")
    seconds: float = Field(description="Wall time of the generation.")


#: Fields added with lenses and recordings: left out of gt/synth.json at their defaults, so cases
#: made without them keep their bytes.
OPTICS_DEFAULTS = {"lens": "pinhole", "fov_diag_deg": None, "vignetting": 0.0}
RECORDING_DEFAULTS = {
    "step_mm": 1.0,
    "pauses": 0,
    "pause_frames": 25,
    "blurred": 0.0,
    "washed_out": 0.0,
    "fps": 15,
}


def intrinsics_for(cfg: SynthConfig) -> Camera:
    """Square pixels, principal point at the image centre (pixel-centre coords), the lens."""
    return lens_camera(cfg.width, cfg.height, cfg.lens, cfg.fov_deg, cfg.fov_diag_deg)


def describe(cfg: SynthConfig, intr: Camera, events: Events) -> dict:
    """The config and, when used, the lens, vignetting and events, for gt/synth.json."""
    defaults = {**OPTICS_DEFAULTS, **RECORDING_DEFAULTS}
    unset = {k for k, v in defaults.items() if getattr(cfg, k) == v}
    meta: dict = {"config": cfg.model_dump(exclude=unset)}
    if events.paused or events.blurred or events.washed_out:
        meta["events"] = events.model_dump()
    if cfg.lens != "pinhole" or cfg.fov_diag_deg is not None:
        meta["lens"] = {
            "name": cfg.lens,
            "model": intr.model,
            "dist": list(LENSES[cfg.lens].dist or []),
            "fx": intr.fx,
            "fov_diag_deg": cfg.fov_diag_deg or LENSES[cfg.lens].fov_diag_deg,
        }
    if cfg.vignetting:
        meta["vignetting"] = {
            "strength": cfg.vignetting,
            "gain": "1 - strength * (r / r_corner)^2 on linear light, before the gamma; r from "
            "the principal point (px), r_corner to the farthest outer image corner",
        }
    return meta


def _streams(seed: int) -> dict[str, np.random.Generator]:
    """Independent generators, so changing one part (e.g. texture) leaves the others alone."""
    names = ("scene", "path", "texture", "bound", "events")  # a new name goes last
    seqs = np.random.SeedSequence(seed).spawn(len(names))
    return {n: np.random.default_rng(s) for n, s in zip(names, seqs, strict=True)}


def build_scene(
    cfg: SynthConfig, rng: dict[str, np.random.Generator], events: Events
) -> tuple[Scene, np.ndarray]:
    """The anatomy and the camera poses (N,4,4) moving through it (still at paused frames)."""
    still = events.still_mask(cfg.frames)
    if cfg.shape == "colon":
        scene = ColonScene(rng["scene"], z_end=cfg.frames * cfg.step_mm * 1.3 + 5.0)
        if scene.min_wall_radius() < scene.AXIS_CORE + 1.0:  # the tracer's bound relies on it
            raise RuntimeError("synthetic colon: folds reach the axis core")
        poses = colon_poses(scene, cfg.frames, rng["path"], cfg.step_mm, still)
    else:
        scene = CavityScene(rng["scene"])
        poses = cavity_poses(scene, cfg.frames, rng["path"], cfg.step_mm, still)
    clearance = scene.f_points(poses[:, :3, 3])
    if clearance.max() > -2.0:
        raise RuntimeError("synthetic camera path comes too close to the wall")
    return scene, poses


def centerline_radii(scene: Scene, bound: StepBound, hits: np.ndarray) -> tuple:
    """Centre-axis points and the mean distance to the wall in each one's normal plane."""
    cs = scene.cross_sections(hits)
    ang = np.linspace(0.0, 2.0 * np.pi, 72, endpoint=False)
    dirs = np.cos(ang)[None, :, None] * cs.u[:, None] + np.sin(ang)[None, :, None] * cs.v[:, None]
    origins = np.repeat(cs.points, len(ang), axis=0)
    t = trace(scene, bound, origins, dirs.reshape(-1, 3))[0].reshape(len(cs.points), len(ang))
    return cs.points, np.nanmean(t, axis=1)


@dataclass
class Setup:
    """Everything fixed for a whole sequence, before the first frame is rendered."""

    scene: Scene
    poses: np.ndarray
    bound: StepBound
    guide: MeshGuide | None
    texture: MucosaTexture
    intr: Camera
    light: Lighting
    events: Events
    gain: np.ndarray | None = None  # (H, W) vignetting on linear light

    def trace(self, i: int, intr: Camera | None = None) -> FrameGeometry:
        return trace_frame(self.scene, self.bound, self.guide, intr or self.intr, self.poses[i])


def prepare(cfg: SynthConfig) -> Setup:
    """Scene, camera path, tracer bounds, texture and the sequence's fixed exposure."""
    rng = _streams(cfg.seed)
    events = plan_events(
        cfg.frames, cfg.pauses, cfg.pause_frames, cfg.blurred, cfg.washed_out, rng["events"]
    )
    scene, poses = build_scene(cfg, rng, events)
    bound = StepBound(scene, rng["bound"])
    big = cfg.frames * cfg.width * cfg.height > GUIDE_RAYS
    guide = MeshGuide(scene, *scene.mesh()) if big else None
    texture = MucosaTexture(rng["texture"], cfg.texture_contrast)
    intr = intrinsics_for(cfg)
    gain = vignetting_gain(intr, cfg.vignetting)
    setup = Setup(scene, poses, bound, guide, texture, intr, Lighting(exposure=1.0), events, gain)
    # Exposure from quarter-resolution previews of three frames, then fixed for the sequence.
    small = intr.scaled(max(cfg.width // 4, 8), max(cfg.height // 4, 8))
    probes = [setup.trace(i, small) for i in sorted({0, cfg.frames // 2, cfg.frames - 1})]
    setup.light = Lighting(exposure=calibrate_exposure(probes, texture), specular=cfg.specular)
    return setup


def _render_frames(
    setup: Setup,
    cfg: SynthConfig,
    writer: CaseWriter,
    progress: Callable[[int, int], None] | None,
) -> tuple[np.ndarray, float]:
    """Render and write every frame; returns the bounding box of all hits and the mean
    fraction of specular pixels."""
    lo, hi, spec_frac = [], [], []
    for i in range(cfg.frames):
        geom = setup.trace(i)
        noise_rng = np.random.default_rng([cfg.seed, 7919, i])  # per frame: order-independent
        rgb, spec = shade(geom, setup.texture, setup.light, cfg.noise_std, noise_rng, setup.gain)
        rgb = spoil(rgb, setup.events.kind_of(i), noise_rng)
        writer.add_frame(rgb, geom.depth, spec)
        lo.append(geom.points.min(0))
        hi.append(geom.points.max(0))
        spec_frac.append(float(spec.mean()))
        if progress is not None:
            progress(i + 1, cfg.frames)
    return np.stack([np.min(lo, 0), np.max(hi, 0)]), float(np.mean(spec_frac))


def generate_case(
    out: Path, cfg: SynthConfig, progress: Callable[[int, int], None] | None = None
) -> SynthSummary:
    """Render a synthetic case into the folder `out`: replaced if it holds a previous synth
    case, a FileExistsError if it is some other non-empty folder. `progress(done, total)` is
    called after each frame."""
    start = time.perf_counter()
    writer = CaseWriter(out, intrinsics_for(cfg), cfg.fps)  # refuses a foreign folder first
    try:
        setup = prepare(cfg)
        extent, spec_frac = _render_frames(setup, cfg, writer, progress)
        points, radius = centerline_radii(setup.scene, setup.bound, extent)
        steps = np.linalg.norm(np.diff(setup.poses[:, :3, 3], axis=0), axis=1)
        meta = {
            "generator": "endopipe synth",
            **describe(cfg, setup.intr, setup.events),
            "exposure": setup.light.exposure,
            "specular_fraction": spec_frac,
            "camera_start": setup.poses[0][:3, 3].tolist(),
        }
        writer.finish(setup.poses, setup.scene.mesh(extent), (points, radius), meta)
    except BaseException:
        writer.abort()
        raise
    return SynthSummary(
        out=str(out),
        frames=cfg.frames,
        path_length_mm=float(steps.sum()),
        mean_radius_mm=float(np.mean(radius)),
        seconds=time.perf_counter() - start,
    )
