"""The scope's photometric model in the NeRF: the radial falloff, gamma and exposure, the angle to
the optical axis on every render path, and that fitting the shading recovers a known model."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from endopipe.stages.camera import Camera
from endopipe.stages.nerf.config import NerfConfig
from endopipe.stages.nerf.model import NEW_KEYS, NerfModel
from endopipe.stages.nerf.render import load_model, render_image, save_model
from endopipe.stages.nerf.scene import SceneBox
from tests.tube_scene import (  # noqa: F401 - one_torch_thread is a fixture
    H,
    W,
    one_torch_thread,
    tiny_config,
    tiny_setup,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


# --- the scope's photometric model --------------------------------------------------------------


def photometric_config(**shading) -> NerfConfig:
    cfg = tiny_config()
    for k, v in shading.items():
        setattr(cfg.shading, k, v)
    return cfg


def flat_wall(cfg: NerfConfig, z: float = 1.0):
    """A distorted wide-angle camera (up to 68 degrees off its axis) at a random rotation
    facing a flat wall, at z-depth `z` in frame 0 and z + 0.5 f in frame f (the distance
    tells the 1/r^2 light from the ambient): rays, the exact surface (depth, normal), a
    textured albedo, the frame of each ray (1..5; frame 0 is held out), the truth of
    cos theta."""
    from endopipe.stages.camera import pixel_directions

    k = Camera(
        width=64,
        height=48,
        fx=20.0,
        fy=20.0,
        cx=31.5,
        cy=23.5,
        model="opencv",
        dist=[-0.1, 0.01, 0.0, 0.0],
    )
    vv, uu = torch.meshgrid(torch.arange(48.0), torch.arange(64.0), indexing="ij")
    dc = pixel_directions(k, uu.reshape(-1), vv.reshape(-1))  # lens undone, z = 1
    rot = torch.as_tensor(
        cv2.Rodrigues(np.array([0.4, -0.7, 1.1]))[0], dtype=torch.float32
    )  # poses only rotate directions
    d = dc @ rot.T
    g = torch.Generator().manual_seed(0)
    albedo = 0.25 + 0.5 * torch.rand(len(d), 3, generator=g)
    frame = torch.randint(1, 6, (len(d),), generator=g)
    surface = {
        "depth": z + 0.5 * frame.float(),
        "normal": (rot @ torch.tensor([0.0, 0.0, -1.0])).expand_as(d),
    }
    cos_truth = dc[:, 2] / dc.norm(dim=-1)
    model = NerfModel(cfg, SceneBox(np.zeros(3), np.eye(3), 1.0, -np.ones(3), np.ones(3)), 6)
    model.set_trained_frames([1, 2, 3, 4, 5])
    with torch.no_grad():
        model.log_gain.fill_(math.log(4 * z * z))  # on the axis in frame 2: gain / r^2 = 1
    return model, d, surface, albedo, frame, cos_truth


def shade(model, d, surface, albedo, frame) -> torch.Tensor:
    return model.shade(surface, albedo, d, d.norm(dim=-1), frame, 1.0)


def fit_shading(model, d, surface, albedo, frame, target, steps: int = 3000) -> None:
    """Fit only what the model's optimiser groups call shading and photometric (field frozen)."""
    groups = [g for g in model.param_groups(0.02, 1e-3) if g["name"] in ("shading", "photometric")]
    opt = torch.optim.Adam([p for g in groups for p in g["params"]], lr=0.03)
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, 0.01 ** (1 / steps))
    for _ in range(steps):
        opt.zero_grad()
        (shade(model, d, surface, albedo, frame) - target).square().mean().backward()
        opt.step()
        sched.step()


def test_radial_falloff_is_flat_at_start_and_old_checkpoints_render_unchanged(tmp_path):
    cfg = photometric_config(falloff="learned", learn_gamma=True, exposure=True)
    model, d, surface, albedo, frame, _ = flat_wall(cfg)
    seed_model = flat_wall(photometric_config())[0]
    assert torch.equal(model.radial_falloff(torch.rand(50)), torch.ones(50))
    new, old = shade(model, d, surface, albedo, frame), shade(seed_model, d, surface, albedo, frame)
    assert torch.allclose(new, old, rtol=1e-6, atol=1e-7)

    # A model.pt written before the photometric model (no such keys in its config or state),
    # opened now that they may be on by default: it loads and renders as before.
    frames, train, held, prior, box, k, poses, _ = tiny_setup(tiny_config(), n_frames=4)
    before = NerfModel(tiny_config(), box, frames.n, gain=50.0).eval()
    save_model(tmp_path / "model.pt", before)
    blob = torch.load(tmp_path / "model.pt", weights_only=False)
    for key in ("falloff", "learn_gamma", "lr"):
        del blob["config"]["shading"][key]
    blob["state"] = {k_: v for k_, v in blob["state"].items() if k_ not in NEW_KEYS}
    blob["config"]["shading"].update(exposure=True)
    torch.save(blob, tmp_path / "old.pt")
    loaded = load_model(tmp_path / "old.pt")
    assert loaded.cfg.shading.falloff == "none" and torch.equal(loaded.falloff, torch.zeros(3))
    blob["config"]["shading"].update(falloff="learned", learn_gamma=True)
    torch.save(blob, tmp_path / "old_new_defaults.pt")
    loaded = load_model(tmp_path / "old_new_defaults.pt")
    ref = render_image(before, prior, k, poses[0])["rgb"]
    assert np.allclose(render_image(loaded, prior, k, poses[0])["rgb"], ref, atol=1e-5)


@pytest.mark.parametrize("piece", ["falloff", "gamma", "exposure"])
def test_fitting_the_shading_recovers_a_known_photometric_model(piece):
    on = {
        "falloff": {"falloff": "learned"},
        "gamma": {"learn_gamma": True},
        "exposure": {"exposure": True},
    }[piece]
    truth, d, surface, albedo, frame, _ = flat_wall(photometric_config(**on))
    exposure = torch.tensor([0.0, 0.3, -0.2, 0.1, -0.4, 0.2])  # frame 0 held out
    with torch.no_grad():
        truth.falloff.copy_(torch.tensor([-1.2, 0.0, 0.0]))
        truth.log_gamma.fill_(math.log(1.6))  # from 2.2: 27% off
        # one gain for the three channels; the mean over trained frames is the gauge
        truth.exposure.copy_((exposure + 0.5)[:, None].expand(-1, 3))
        truth.ambient_raw.fill_(math.log(math.expm1(0.05)))
        target = shade(truth, d, surface, albedo, frame)
    model = flat_wall(photometric_config(**on))[0]
    fit_shading(model, d, surface, albedo, frame, target)
    with torch.no_grad():
        if piece == "falloff":
            assert abs(model.falloff[0].item() + 1.2) < 0.12, model.falloff
            c = torch.linspace(0.5, 1.0, 20)
            assert torch.allclose(model.radial_falloff(c), truth.radial_falloff(c), rtol=0.01)
        elif piece == "gamma":
            assert abs(float(model.gamma()) - 1.6) < 0.16, model.gamma()
        else:
            got = model._exposure_centred()
            want = exposure[1:, None].expand(-1, 3)
            assert torch.allclose(got[1:], want, atol=0.1 * 0.1), got
            # The held-out frame has no trained exposure: it takes its trained neighbour's (the
            # first trained frame's, before which it comes).
            held, neighbour = torch.zeros_like(frame), torch.ones_like(frame)
            assert torch.equal(
                shade(model, d, surface, albedo, held), shade(model, d, surface, albedo, neighbour)
            )


def test_every_render_path_sees_the_angle_to_the_optical_axis():
    """render_image with a distorted lens: the falloff uses the lens-undone ray's angle."""
    from endopipe.stages.camera import image_directions

    cfg = photometric_config(falloff="learned")
    frames, train, held, prior, box, _, poses, _ = tiny_setup(cfg, n_frames=4)
    f = 0.5 * W / np.tan(np.radians(50))
    k = Camera(
        width=W,
        height=H,
        fx=f,
        fy=f,
        cx=(W - 1) / 2,
        cy=(H - 1) / 2,
        model="opencv",
        dist=[-0.3, 0.08, 0.0, 0.0],
    )
    model = NerfModel(cfg, box, frames.n, gain=1e-3).eval()  # dim: no channel clips at 1
    flat = render_image(model, prior, k, poses[1])["rgb"]
    with torch.no_grad():
        model.falloff.copy_(torch.tensor([-1.0, 0.5, 0.0]))
    dimmed = render_image(model, prior, k, poses[1])["rgb"]
    dirs = image_directions(k)
    x = 1.0 - dirs[..., 2] / np.linalg.norm(dirs, axis=-1)
    expected = np.exp(-1.0 * x + 0.5 * x**2)
    assert x.max() > 0.3
    ratio = (dimmed / flat) ** cfg.shading.gamma
    assert np.allclose(ratio, expected[..., None], rtol=1e-3)


def test_the_normal_term_dims_a_tilted_wall_by_its_cosine_and_off_ignores_the_tilt():
    """n.l is the shading's cue to shape; off, only the distance lights the wall."""
    for normal_term in (True, False):
        model, d, surface, albedo, frame, _ = flat_wall(photometric_config(normal_term=normal_term))
        with torch.no_grad():
            model.ambient_raw.fill_(-30.0)  # no ambient: the light is gain cos / r^2 alone
            facing = -d / d.norm(dim=-1, keepdim=True)
            lit = shade(model, d, {**surface, "normal": facing}, albedo, frame)
            axis = torch.linalg.cross(facing, torch.tensor([1.0, 0.0, 0.0]).expand_as(d))
            tilt = math.radians(60)
            axis = axis / axis.norm(dim=-1, keepdim=True)
            tilted = math.cos(tilt) * facing + math.sin(tilt) * axis
            dimmed = shade(model, d, {**surface, "normal": tilted}, albedo, frame)
        gamma = model.cfg.shading.gamma
        ratio = (dimmed / lit) ** gamma
        expected = math.cos(tilt) if normal_term else 1.0
        assert torch.allclose(ratio, torch.full_like(ratio, expected), rtol=1e-3)


def test_a_view_lit_from_another_camera_is_shaded_from_that_light():
    """A rectified rig's right eye is lit by the scope's light at the left eye: shaded from the
    light's pose, the wall gets gain cos / r^2 with r and the angle to that light (computed here
    from the geometry), and a light at the rays' own camera shades as the default does."""
    cfg = photometric_config(falloff="learned")
    model, d, surface, albedo, frame, _ = flat_wall(cfg)
    rot = torch.as_tensor(cv2.Rodrigues(np.array([0.4, -0.7, 1.1]))[0], dtype=torch.float32)
    origins = torch.zeros_like(d)
    with torch.no_grad():
        model.falloff.copy_(torch.tensor([-0.8, 0.3, -0.1]))
        own = torch.eye(4)
        own[:3, :3] = rot
        at_camera = model.shade(surface, albedo, d, d.norm(dim=-1), frame, 1.0, (own, origins))
        assert torch.allclose(at_camera, shade(model, d, surface, albedo, frame), rtol=1e-5)

        model.falloff.zero_()
        model.ambient_raw.fill_(-30.0)  # no ambient: gain cos / r^2 alone
        left = own.clone()
        left[:3, 3] = rot @ torch.tensor([-0.3, 0.0, 0.0])  # the light 0.3 to the camera's left
        moved = model.shade(surface, albedo, d, d.norm(dim=-1), frame, 1.0, (left, origins))
        unmoved = shade(model, d, surface, albedo, frame)
    points = d * surface["depth"][:, None]
    to_light = left[:3, 3] - points
    r = to_light.norm(dim=-1)
    cos = (surface["normal"] * to_light).sum(-1) / r
    expected = albedo * (model.log_gain.exp() * cos / r.square())[:, None]
    expected = expected ** (1.0 / cfg.shading.gamma)
    assert torch.allclose(moved, expected, rtol=1e-4)
    assert (moved - unmoved).abs().mean() > 0.01  # the moved light is not the camera's
