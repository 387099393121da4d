"""Volume rendering against analytic currents: a disk seen face-on, a uniform fog, the camera model, the
importance sampler, turntables and the 2D picture with metric ellipses."""

import math

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from matplotlib.collections import EllipseCollection
from torch import nn

from deepcurrents.errors import ConfigError, UserInputError
from deepcurrents.eval.plots import normal_colors
from deepcurrents.eval.render import (
    Camera,
    DensitySettings,
    ffmpeg_executable,
    proposal_grid,
    render_current,
    render_current_2d,
    save_gif,
    save_mp4,
)
from deepcurrents.eval.render.volume import _sample_along
from deepcurrents.geometry import circle
from deepcurrents.nn import neural_current

JUMP_3D = 4 * math.pi


class AnalyticDisk(nn.Module):
    """The current of a disk of radius R through the origin with unit normal n, smeared across the disk by
    a Gaussian of standard deviation h (mass jump·alpha_scale per unit area, as an ideal sheet has):
    ω(x) = jump·a·n·g_h(x·n)·s(ρ), s a sharp sigmoid step at ρ = R. Γ is the disk's rim."""

    def __init__(self, radius=0.5, normal=(0.0, 0.0, 1.0), h=0.04, edge=0.002, alpha_scale=1e-3):
        super().__init__()
        self.dim, self.alpha_scale, self.radius, self.h, self.edge = 3, alpha_scale, radius, h, edge
        n = torch.tensor(normal, dtype=torch.float64)
        self.n = n / n.norm()
        self.loops = [torch.as_tensor(circle(radius, normal=tuple(self.n.tolist()), n=128), dtype=torch.float32)]

    def profile(self, z: torch.Tensor) -> torch.Tensor:
        return torch.exp(-0.5 * (z / self.h) ** 2) / (self.h * math.sqrt(2 * math.pi))

    def evaluate(self, x, chunk_size=1 << 15, omega=True):
        x = x.double()
        z = x @ self.n
        rho = (x - z[:, None] * self.n).norm(dim=-1)
        step = torch.sigmoid((self.radius - rho) / self.edge)
        f = JUMP_3D * self.alpha_scale * 0.5 * (1 + torch.erf(z / (self.h * math.sqrt(2)))) * step
        w = JUMP_3D * self.alpha_scale * (self.profile(z) * step)[:, None] * self.n
        return (f.float(), w.float()) if omega else f.float()


class UniformField(nn.Module):
    """ω = c·e_z everywhere in the domain (no boundary): a fog of constant density."""

    def __init__(self, c=0.02, alpha_scale=1e-3):
        super().__init__()
        self.dim, self.alpha_scale, self.c, self.loops = 3, alpha_scale, c, []

    def evaluate(self, x, chunk_size=1 << 15, omega=True):
        w = torch.zeros_like(x)
        w[:, 2] = self.c
        return (torch.zeros(len(x)), w) if omega else torch.zeros(len(x))


def face_on_camera(normal, size=64, distance=3.0, fov=30.0):
    n = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    return Camera(azimuth=math.degrees(math.atan2(n[1], n[0])), elevation=math.degrees(math.asin(n[2])),
                  distance=distance, fov=fov, target=(0.0, 0.0, 0.0), width=size, height=size)


@pytest.mark.parametrize("normal", [(0.0, 0.0, 1.0), (1.0, 1.0, 1.0)])
def test_disk_face_on_covers_the_projected_disk_in_the_normals_colour(normal):
    disk = AnalyticDisk(normal=normal)
    camera = face_on_camera(normal)
    settings = DensitySettings(gain=3.0, floor=2.5e-3)
    image = render_current(disk, camera, samples=48, grid=24, settings=settings, curves=False)
    # opacity through the disk's centre: brute-force quadrature of the density across the sheet
    z = np.linspace(-0.5, 0.5, 200_001)
    omega = JUMP_3D * disk.alpha_scale * disk.profile(torch.as_tensor(z)).numpy()
    sigma = settings.gain * np.maximum(omega - settings.floor, 0) / (JUMP_3D * disk.alpha_scale)
    expected = 1 - math.exp(-np.trapezoid(sigma, z))
    centre = image.alpha[31:33, 31:33]
    assert np.allclose(centre, expected, rtol=0.01)
    # the covered pixels form the disk's pinhole projection: radius R·focal/distance
    covered = image.alpha > 0.5 * expected
    radius_px = disk.radius * camera.focal / camera.distance
    assert covered.sum() == pytest.approx(math.pi * radius_px**2, rel=0.04)
    rows, cols = np.nonzero(covered)
    assert abs(rows.mean() - 31.5) < 0.5 and abs(cols.mean() - 31.5) < 0.5
    # their colour is the normal's colour (premultiplied colour / opacity)
    colour = image.color[covered] / image.alpha[covered][:, None]
    assert np.abs(colour - normal_colors(np.asarray([normal]))).max() < 0.01


def test_boundary_curve_is_drawn_on_the_rim():
    disk = AnalyticDisk()
    camera = face_on_camera((0, 0, 1))
    image = render_current(disk, camera, samples=16, grid=16, curves=True, curve_width=2.0).over()
    radius_px = disk.radius * camera.focal / camera.distance
    rim = image[30:34, int(round(31.5 + radius_px)) - 1: int(round(31.5 + radius_px)) + 2]
    inside = image[30:34, 30:34]
    assert rim.min() < 30  # black line
    assert inside.min() > 60  # no line across the disk


def test_uniform_fog_gets_its_exact_optical_depth():
    fog = UniformField(c=0.02)
    settings = DensitySettings(gain=1.0, floor=2.5e-3)
    camera = Camera(azimuth=0.0, elevation=90.0, distance=3.0, fov=20.0, width=9, height=9)
    image = render_current(fog, camera, samples=16, grid=8, settings=settings)
    sigma = settings.gain * (fog.c - settings.floor) / (JUMP_3D * fog.alpha_scale)
    # the centre ray crosses the whole domain [-1, 1] along z
    assert image.alpha[4, 4] == pytest.approx(1 - math.exp(-2.0 * sigma), rel=1e-4)
    assert np.allclose(image.color[4, 4] / image.alpha[4, 4], normal_colors(np.array([[0, 0, 1.0]]))[0],
                       atol=1e-5)


def test_support_box_holds_the_disk_and_little_more():
    grid = proposal_grid(AnalyticDisk(h=0.03), resolution=24)
    lo, hi = grid.support
    assert np.all(lo[:2] <= -0.5) and np.all(hi[:2] >= 0.5)
    assert hi[2] - lo[2] < 0.5  # a thin slab around z = 0, not the whole domain
    assert proposal_grid(UniformField(c=1e-4), resolution=8).support is None  # below the floor: empty


def test_quantile_sampling_follows_the_pdf():
    t0, t1 = torch.tensor([0.0, 1.0]), torch.tensor([1.0, 3.0])
    uniform = torch.full((2, 4), 0.25)
    t = _sample_along(t0, t1, uniform, 4)
    assert torch.allclose(t[0], torch.tensor([0.125, 0.375, 0.625, 0.875]))
    assert torch.allclose(t[1], 1.0 + 2.0 * torch.tensor([0.125, 0.375, 0.625, 0.875]))
    spike = torch.tensor([[0.0, 0.0, 1.0, 0.0]] * 2)
    t = _sample_along(t0, t1, spike, 8)
    assert torch.all(t[0] >= 0.5) and torch.all(t[0] <= 0.75)  # all inside the third bin
    assert torch.all(t[:, 1:] >= t[:, :-1])


def test_camera_rays_and_projection_agree():
    camera = Camera(azimuth=20.0, elevation=-35.0, distance=2.5, fov=50.0, target=(0.1, -0.2, 0.3),
                    width=11, height=7)
    origins, dirs = camera.rays()
    pts = (origins + 1.7 * dirs).double().numpy()
    col, row, dist = camera.project(pts)
    expected_rows, expected_cols = np.divmod(np.arange(11 * 7), 11)
    assert np.allclose(col, expected_cols, atol=1e-4) and np.allclose(row, expected_rows, atol=1e-4)
    assert np.allclose(dist, 1.7, atol=1e-5)
    eye, right, up, forward = camera.basis()
    assert np.allclose(eye + camera.distance * forward, camera.target)
    assert np.allclose([right @ up, right @ forward, up @ forward], 0, atol=1e-12)
    assert up[2] > 0  # z is up in the picture


def test_bad_cameras_say_so_in_one_sentence():
    with pytest.raises(ConfigError, match="camera.width"):
        Camera(width=0)
    with pytest.raises(ConfigError, match="camera.fov"):
        Camera(fov=180.0)
    with pytest.raises(ConfigError, match="camera.distance"):
        Camera(distance=-1.0)
    away = Camera(azimuth=0.0, elevation=0.0, distance=2.0, target=(10.0, 10.0, 10.0), width=8, height=8)
    with pytest.raises(UserInputError, match="sees nothing"):
        render_current(AnalyticDisk(), away, samples=4, grid=8)


def test_turntable_has_the_requested_frames(tmp_path):
    disk = AnalyticDisk(normal=(1.0, 0.0, 1.0))
    camera = Camera(azimuth=0.0, elevation=20.0, distance=3.0, width=16, height=12)
    cameras = camera.turntable(5)
    assert [c.azimuth for c in cameras] == [0.0, 72.0, 144.0, 216.0, 288.0]
    grid = proposal_grid(disk, 8)  # one proposal grid for every frame
    frames = [render_current(disk, c, grid=grid, samples=6).over() for c in cameras]
    assert len(frames) == 5 and all(f.shape == (12, 16, 3) and f.dtype == np.uint8 for f in frames)
    assert not np.array_equal(frames[0], frames[1])  # the camera moved
    gif = save_gif(frames, tmp_path / "t.gif")
    assert iio.imread(gif, index=None).shape[:3] == (5, 12, 16)
    mp4 = save_mp4(frames, tmp_path / "t.mp4", fps=5)
    if ffmpeg_executable() is None:
        assert mp4 is None
    else:
        import imageio_ffmpeg

        assert imageio_ffmpeg.count_frames_and_secs(str(mp4))[0] == 5
    with pytest.raises(ConfigError, match="frames"):
        camera.turntable(0)


def test_2d_picture_draws_the_metric_as_oriented_ellipses(tmp_path):
    torch.manual_seed(0)
    current = neural_current(2, poles=torch.tensor([[-0.5, 0.0], [0.5, 0.0]]), signs=torch.tensor([-1.0, 1.0]),
                            num_frequencies=8, width=8, depth=1)

    def metric(x):  # B = diag(1, 0): only the x component of ω costs
        b = torch.zeros(len(x), 2, 2)
        b[:, 0, 0] = 1.0
        return b

    fig = render_current_2d(current, None, curves=[np.array([[-0.5, 0.0], [0.5, 0.0]])], metric_fn=metric,
                            resolution=21, arrows=5)
    ellipses = [c for c in fig.axes[0].collections if isinstance(c, EllipseCollection)]
    assert len(ellipses) == 1
    e = ellipses[0]
    assert len(e.get_offsets()) == 25
    assert np.allclose(np.asarray(e.get_angles()) % 180, 0) and np.all(e.get_widths() > 5 * e.get_heights())
    path = tmp_path / "fig3.png"
    render_current_2d(current, path, curves=[], resolution=21, arrows=5)
    assert iio.imread(path).ndim == 3


def test_a_2d_reconstruction_gets_its_metric_picture_from_the_render_app(tmp_path):
    """Fig. 3d: the semicircle target's metric B = I − n nᵀ (data.recon.CurveMetricDataModule.metric_fn) drawn by
    `render` as render_metric.png beside render.png; B by hand at two points (above the middle of the arc: n
    vertical, so B keeps x only; beyond an end: I)."""
    from conftest import QUIET_CPU, ROOT, compose_cfg, run_command_in_process

    from deepcurrents.cli.render import metric_of
    from deepcurrents.data.recon import CurveMetricDataModule
    from deepcurrents.experiments.runner import train
    from deepcurrents.models.loading import load_module

    data = CurveMetricDataModule(radius=0.5)
    b = data.metric_fn(torch.tensor([[0.0, 0.8], [-0.9, -0.3]], dtype=torch.float64))
    # the arc is 200 segments: the closest one's normal is π/400 off vertical there
    assert torch.allclose(b[0], torch.tensor([[1.0, 0.0], [0.0, 0.0]], dtype=torch.float64), atol=1e-2)
    assert torch.allclose(b[1], torch.eye(2, dtype=torch.float64))
    train(compose_cfg(["experiment=recon_2d_semicircle", *QUIET_CPU, "trainer.max_steps=2", "data.num_samples=64",
                       "model.rff.num_frequencies=8", "model.net.width=8", "model.net.depth=1",
                       "evaluation.mass_samples=4096", "evaluation.curve.resolution=32"]), out_dir=tmp_path / "run")
    ckpt = tmp_path / "run" / "checkpoints" / "last.ckpt"
    metric = metric_of(load_module(ckpt))
    assert metric is not None and torch.allclose(metric(torch.tensor([[0.0, 0.8]])), b[0].float(), atol=1e-6)
    proc = run_command_in_process("deepcurrents.cli.render", [f"ckpt_path={ckpt}", f"out_dir={tmp_path / 'pictures'}"],
                                  cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert sorted(p.name for p in (tmp_path / "pictures").iterdir()) == ["render.png", "render_metric.png"]


def test_final_media_log_the_mesh_picture_and_the_3d_mesh_under_keys_of_their_own(tmp_path, monkeypatch):
    """MediaCallback.on_final_evaluation with W&B: the render, mesh.png, the mesh as a 3D object and the metrics
    each under its own key (mesh.png and the 3D mesh shared "media/final_mesh", so the picture was never logged)."""
    from types import SimpleNamespace

    from conftest import QUIET_CPU, TINY_EVAL, TINY_NET, compose_cfg

    import deepcurrents.models.callbacks as callbacks
    from deepcurrents.experiments.runner import train
    from deepcurrents.models.loading import load_module

    out = tmp_path / "run"
    metrics = train(compose_cfg(["experiment=minimal_trefoil", *QUIET_CPU, *TINY_NET, *TINY_EVAL,
                                 "trainer.max_steps=2"]), out_dir=out)
    assert (out / "mesh.png").is_file() and (out / "mesh.ply").is_file()
    logged = []
    fake = SimpleNamespace(experiment=SimpleNamespace(log=lambda media, step: logged.append(media)))
    monkeypatch.setattr(callbacks, "_wandb_loggers", lambda trainer: [fake])
    media = callbacks.MediaCallback(final=True, size=24, samples=4, grid=8)
    module = load_module(out / "checkpoints" / "last.ckpt")
    media.on_final_evaluation(SimpleNamespace(is_global_zero=True, datamodule=None), module, metrics, out)
    (keys,) = [set(m) for m in logged]
    assert keys == {"media/final_render", "media/final_mesh_picture", "media/final_mesh", "media/final_metrics"}
