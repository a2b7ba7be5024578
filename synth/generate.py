"""A synthetic endoscopy case with exact ground truth, written as an endopipe case folder
(docs/formats.md).

A seeded implicit anatomy (colon or cavity) is ray-cast exactly from a seeded camera path with a
light at the camera; the case gets the video, lossless frames, intrinsics, z-depth, poses, mesh,
specular masks and centre line. Units are millimetres throughout. The camera may have a distorted
lens and vignetting (`lens.py`): each pixel's ray is its undistorted direction, so the depth
stays exact on the frames' own pixel grid. The anatomy may move (`deform.py`: breathing, or a
patch pulled by a tool, `tool.py`): frame i is cast against the wall at its time i / fps, and
the camera may stand still for the whole clip.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from endopipe.stages.camera import Camera
from endopipe.synth.deform import Breathe, DeformedScene, Displacement
from endopipe.synth.events import Events, plan_events, spoil
from endopipe.synth.lens import LENSES, LensName, lens_camera, vignetting_gain
from endopipe.synth.raycast import (
    FrameGeometry,
    MeshGuide,
    StepBound,
    camera_rays,
    trace,
    trace_frame,
)
from endopipe.synth.render import Lighting, calibrate_exposure, shade
from endopipe.synth.scene import CavityScene, ColonScene, Scene
from endopipe.synth.texture import MucosaTexture
from endopipe.synth.tool import Tool, ToolHit, plan_pull, shade_tool
from endopipe.synth.trajectory import cavity_poses, colon_poses
from endopipe.synth.writer import CaseWriter, Layout

__all__ = ["Layout", "SynthConfig", "SynthSummary", "generate_case"]

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
        "OpenCV equidistant k1 -0.05, k2 0.01 (140 deg diagonal); c3vd: C3VD's colonoscope (its "
        "published calibration; a 5:4 image).",
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
    deform: Literal["none", "breathe", "pull"] = Field(
        "none",
        description="none: a rigid anatomy; breathe: the wall moves out and back periodically; "
        "pull: a patch of wall pulled a few mm by a grasping tool that is in view.",
    )
    deform_amplitude: float | None = Field(
        None,
        gt=0.0,
        description="breathe: the radius's largest relative change (default 0.04); pull: the "
        "pulled spot's largest displacement, mm (default 4).",
    )
    breathe_period_s: float = Field(3.0, gt=0.1, description="Period of the breathing, s.")
    still_camera: bool = Field(
        False, description="Every frame at the first pose of the path (the scene may move)."
    )
    stereo_baseline_mm: float | None = Field(
        None,
        gt=0.0,
        le=50.0,
        description="A right eye too: the same scene rendered from each frame's camera moved "
        "this far along its +x, mm (a rectified pair; each eye lit from its own centre). None: "
        "monocular. Needs a layout with a place for it (hamlyn).",
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
    deform: str = Field("none", description="How the anatomy moves (none, breathe, pull).")
    deform_amplitude: float | None = Field(
        None, description="breathe: relative radius change; pull: mm; None when rigid."
    )
    tool: bool = Field(False, description="A tool is in view (masks/ written).")


#: Fields added with lenses and recordings: left out of gt/synth.json at their defaults, so cases
#: made without them keep their bytes.
OPTICS_DEFAULTS = {"lens": "pinhole", "fov_diag_deg": None, "vignetting": 0.0}
DEFORM_DEFAULTS = {
    "deform": "none",
    "deform_amplitude": None,
    "breathe_period_s": 3.0,
    "still_camera": False,
}
#: The deformation's default amplitude, per kind (breathe: relative; pull: mm).
AMPLITUDE = {"breathe": 0.04, "pull": 4.0}
STEREO_DEFAULTS = {"stereo_baseline_mm": None}
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
    defaults = {**OPTICS_DEFAULTS, **RECORDING_DEFAULTS, **DEFORM_DEFAULTS, **STEREO_DEFAULTS}
    unset = {k for k, v in defaults.items() if getattr(cfg, k) == v}
    meta: dict = {"config": cfg.model_dump(exclude=unset)}
    if events.paused or events.blurred or events.washed_out:
        meta["events"] = events.model_dump()
    if cfg.lens != "pinhole" or cfg.fov_diag_deg is not None:
        meta["lens"] = {
            "name": cfg.lens,
            "model": intr.model,
            "dist": list(intr.dist or []),
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
    names = ("scene", "path", "texture", "bound", "events", "deform")  # a new name goes last
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
    disp: Displacement | None = None  # the anatomy's motion; None: rigid
    tool: Tool | None = None  # in view when the wall is pulled
    fps: float = 15.0

    def time(self, i: int) -> float:
        """Frame i's time, s."""
        return i / self.fps

    def scene_at(self, i: int) -> Scene:
        """The anatomy at frame i's time (the rest anatomy when rigid)."""
        if self.disp is None:
            return self.scene
        return DeformedScene(self.scene, self.disp, self.time(i))

    def trace(
        self, i: int, intr: Camera | None = None, pose: np.ndarray | None = None
    ) -> FrameGeometry:
        """The wall at frame i's time, seen from its pose or `pose` (the tool not included)."""
        intr = intr or self.intr
        pose = self.poses[i] if pose is None else pose
        return trace_frame(self.scene_at(i), self.bound, self.guide, intr, pose)

    def tool_hit(self, i: int, pose: np.ndarray | None = None) -> ToolHit | None:
        """Where the tool lies along each of frame i's rays (None: no tool)."""
        if self.tool is None:
            return None
        pose = self.poses[i] if pose is None else pose
        origin, dirs, _ = camera_rays(self.intr, pose)
        return self.tool.cast(origin, dirs, self.time(i))


def plan_deform(
    cfg: SynthConfig, setup: Setup, rng: np.random.Generator
) -> tuple[Displacement | None, Tool | None]:
    """The motion asked for, and the tool that makes it (pull)."""
    if cfg.deform == "none":
        return None, None
    amplitude = cfg.deform_amplitude or AMPLITUDE[cfg.deform]
    if cfg.deform == "breathe":
        return Breathe(setup.scene, rng, amplitude, cfg.breathe_period_s), None
    clip_s = (cfg.frames - 1) / cfg.fps
    return plan_pull(setup.scene, setup.bound, setup.intr, setup.poses[0], amplitude, clip_s)


def check_clearance(setup: Setup) -> None:
    """The camera stays 2 mm inside the lumen at every frame's time."""
    for i, pose in enumerate(setup.poses):
        if setup.scene_at(i).f_points(pose[None, :3, 3])[0] > -2.0:
            raise RuntimeError(f"synthetic wall comes too close to the camera at frame {i}")


def prepare(cfg: SynthConfig) -> Setup:
    """Scene, camera path, tracer bounds, texture and the sequence's fixed exposure."""
    rng = _streams(cfg.seed)
    events = plan_events(
        cfg.frames, cfg.pauses, cfg.pause_frames, cfg.blurred, cfg.washed_out, rng["events"]
    )
    scene, poses = build_scene(cfg, rng, events)
    if cfg.still_camera:
        poses = np.repeat(poses[:1], cfg.frames, axis=0)
    bound = StepBound(scene, rng["bound"])
    texture = MucosaTexture(rng["texture"], cfg.texture_contrast)
    intr = intrinsics_for(cfg)
    gain = vignetting_gain(intr, cfg.vignetting)
    setup = Setup(scene, poses, bound, None, texture, intr, Lighting(exposure=1.0), events, gain)
    setup.fps = float(cfg.fps)
    setup.disp, setup.tool = plan_deform(cfg, setup, rng["deform"])
    if setup.disp is not None:
        check_clearance(setup)
    if cfg.frames * cfg.width * cfg.height > GUIDE_RAYS:
        slack = 0.0 if setup.disp is None else setup.disp.reach
        setup.guide = MeshGuide(scene, *scene.mesh(), slack=slack)
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
        depth, tool = geom.depth, None
        hit = setup.tool_hit(i)
        if hit is not None:
            rgb, depth, spec, tool = put_tool(setup, i, geom, hit, (rgb, spec), noise_rng, cfg)
        rgb = spoil(rgb, setup.events.kind_of(i), noise_rng)
        right = None
        if cfg.stereo_baseline_mm is not None:
            right = render_right(setup, i, cfg, cfg.stereo_baseline_mm)
        writer.add_frame(rgb, depth, spec, tool, right=right)
        lo.append(geom.points.min(0))
        hi.append(geom.points.max(0))
        spec_frac.append(float(spec.mean()))
        if progress is not None:
            progress(i + 1, cfg.frames)
    return np.stack([np.min(lo, 0), np.max(hi, 0)]), float(np.mean(spec_frac))


def right_pose(pose: np.ndarray, baseline_mm: float) -> np.ndarray:
    """The right eye of a rectified pair: the camera moved `baseline_mm` along its own +x."""
    out = pose.copy()
    out[:3, 3] += baseline_mm * pose[:3, 0]
    return out


def render_right(setup: Setup, i: int, cfg: SynthConfig, baseline_mm: float) -> np.ndarray:
    """Frame i's right eye: the same scene, tool and spoiling from the moved camera, with
    sensor noise of its own. The scope has one light: the wall is lit from the left eye's
    centre, so its shading is the left image's (highlights included: a simplification, real
    ones move with the eye)."""
    pose = right_pose(setup.poses[i], baseline_mm)
    geom = lit_from(setup.trace(i, pose=pose), setup.poses[i][:3, 3])
    noise_rng = np.random.default_rng([cfg.seed, 7927, i])
    rgb, spec = shade(geom, setup.texture, setup.light, cfg.noise_std, noise_rng, setup.gain)
    hit = setup.tool_hit(i, pose)
    if hit is not None:
        rgb = put_tool(setup, i, geom, hit, (rgb, spec), noise_rng, cfg, pose)[0]
    return spoil(rgb, setup.events.kind_of(i), noise_rng)


def lit_from(geom: FrameGeometry, light: np.ndarray) -> FrameGeometry:
    """The geometry as shading reads it with the light at `light` instead of at the camera."""
    to_light = light - geom.points
    dist = np.linalg.norm(to_light, axis=1)
    cos = np.einsum("ij,ij->i", geom.normals, to_light) / np.maximum(dist, 1e-12)
    return dataclasses.replace(geom, dist=dist, cos=cos, origin=np.asarray(light, float))


def put_tool(
    setup: Setup,
    i: int,
    geom: FrameGeometry,
    hit: ToolHit,
    image: tuple[np.ndarray, np.ndarray],
    noise_rng: np.random.Generator,
    cfg: SynthConfig,
    pose: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The tool over the tissue where it is nearer along the ray: image, z-depth, specular
    mask and the tool mask (True = tool) of frame i, seen from its pose or `pose`."""
    _, dirs, z_per_t = camera_rays(setup.intr, setup.poses[i] if pose is None else pose)
    tissue_t = np.full(len(dirs), np.inf)
    tissue_t[geom.valid.ravel()] = geom.dist
    front = hit.t < tissue_t
    mine = ToolHit(hit.t[front], hit.normals[front])
    gain = None if setup.gain is None else setup.gain.ravel()[front]
    colours, shiny = shade_tool(mine, dirs[front], setup.light, cfg.noise_std, noise_rng, gain)
    rgb, spec = (a.copy() for a in image)
    shape = geom.depth.shape
    rgb.reshape(-1, 3)[front] = colours
    spec.reshape(-1)[front] = shiny
    depth = geom.depth.copy()
    depth.reshape(-1)[front] = hit.t[front] * z_per_t[front]
    return rgb, depth, spec, front.reshape(shape)


def generate_case(
    out: Path,
    cfg: SynthConfig,
    progress: Callable[[int, int], None] | None = None,
    layout: Layout | None = None,
) -> SynthSummary:
    """Render a synthetic case into the folder `out`: replaced if it holds a previous synth
    case, a FileExistsError if it is some other non-empty folder. `progress(done, total)` is
    called after each frame. `layout` writes another tool's layout too (in its subfolder) or
    instead of endopipe's frames (subfolder "")."""
    start = time.perf_counter()
    if cfg.stereo_baseline_mm is not None and (layout is None or not layout.takes_right):
        where = "endopipe's case folder" if layout is None else f"the {layout.name} layout"
        raise ValueError(f"{where} has no place for a right eye; write a stereo case as hamlyn")
    # refuses a foreign folder first
    writer = CaseWriter(out, intrinsics_for(cfg), cfg.fps, layout)
    try:
        setup = prepare(cfg)
        extent, spec_frac = _render_frames(setup, cfg, writer, progress)
        first = setup.scene_at(0)  # the mesh and centre line: the wall at frame 0's time
        points, radius = centerline_radii(first, setup.bound, extent)
        steps = np.linalg.norm(np.diff(setup.poses[:, :3, 3], axis=0), axis=1)
        meta = {
            "generator": "endopipe synth",
            **describe(cfg, setup.intr, setup.events),
            "exposure": setup.light.exposure,
            "specular_fraction": spec_frac,
            "camera_start": setup.poses[0][:3, 3].tolist(),
            **motion(setup),
        }
        writer.finish(setup.poses, first.mesh(extent), (points, radius), meta)
    except BaseException:
        writer.abort()
        raise
    return SynthSummary(
        out=str(out),
        frames=cfg.frames,
        path_length_mm=float(steps.sum()),
        mean_radius_mm=float(np.mean(radius)),
        seconds=time.perf_counter() - start,
        deform=cfg.deform,
        deform_amplitude=None if setup.disp is None else setup.disp.describe()["amplitude"],
        tool=setup.tool is not None,
    )


def motion(setup: Setup) -> dict:
    """gt/synth.json's account of a moving anatomy and its tool (nothing when rigid)."""
    if setup.disp is None:
        return {}
    meta: dict = {
        "deform": {
            **setup.disp.describe(),
            "frame_time": "frame i is the wall at i / fps s; gt/depth is exact at that time",
            "mesh": "gt/mesh.ply and gt/centerline.json are the wall at frame 0's time",
        }
    }
    if setup.tool is not None:
        meta["tool"] = setup.tool.describe()
    return meta
