"""Pictures meant to be compared share one view: a reconstruction's mesh.png and target.png are drawn from
the same direction, framing the same cube, with faces oriented the same way (along the current), so that
the two colourings (normal → RGB) compare."""

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import trimesh
from conftest import QUIET_CPU, compose_cfg, spherical_cap

from deepcurrents.data.targets import mesh_boundary_loops
from deepcurrents.eval import plots
from deepcurrents.eval.meshing import flux_sign
from deepcurrents.experiments.runner import train
from deepcurrents.models import base, reconstruction


def test_plot_mesh_frames_the_view_it_is_given():
    tet = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    view = plots.mesh_view([np.asarray(tet.vertices), np.array([[2.0, 0.0, 0.0]])], elev=10.0, azim=-70.0)
    # the centre of the five points' bounding box [0, 2] × [0, 1] × [0, 1], half-side 0.55 × its largest extent
    np.testing.assert_allclose(view.center, [1.0, 0.5, 0.5])
    assert abs(view.radius - 0.55 * 2.0) < 1e-12
    fig = plots.plot_mesh(tet, None, None, view=view)
    ax = fig.axes[0]
    assert (ax.elev, ax.azim) == (10.0, -70.0)
    for lim, c in zip((ax.get_xlim3d(), ax.get_ylim3d(), ax.get_zlim3d()), view.center, strict=True):
        np.testing.assert_allclose(lim, (c - view.radius, c + view.radius))
    plt.close(fig)
    # without a view the picture frames its own mesh and loops, as before
    fig = plots.plot_mesh(tet, [np.array([[2.0, 0.0, 0.0], [2.0, 0.1, 0.0], [2.0, 0.0, 0.1]])], None)
    ax = fig.axes[0]  # seven points: box centre (1, 0.5, 0.5), largest extent 2 (x)
    np.testing.assert_allclose(ax.get_xlim3d(), (1 - 1.1, 1 + 1.1))
    np.testing.assert_allclose(ax.get_ylim3d(), (0.5 - 1.1, 0.5 + 1.1))
    assert (ax.elev, ax.azim) == (25.0, 35.0)
    plt.close(fig)


def test_reconstruction_mesh_and_target_pictures_share_one_view(tmp_path, cap_file, monkeypatch):
    drawn = {}
    real = plots.plot_mesh

    def recording(mesh, loops=None, path=None, title=None, **kwargs):
        fig = real(mesh, loops, None, title, **kwargs)
        ax = fig.axes[0]
        drawn[Path(path).name] = {"mesh": mesh, "view": (ax.elev, ax.azim),
                                  "box": np.array([ax.get_xlim3d(), ax.get_ylim3d(), ax.get_zlim3d()])}
        fig.savefig(path)
        plt.close(fig)
        return fig

    monkeypatch.setattr(base, "plot_mesh", recording)
    monkeypatch.setattr(reconstruction, "plot_mesh", recording)
    # two steps from ω ≈ α (the network's output starts at zero); the phase meshes the rim's spanning surface
    cfg = compose_cfg(["experiment=recon_mesh", f"data.mesh={cap_file}", *QUIET_CPU, "data.num_workers=0",
                       "trainer.max_steps=2", "data.num_samples=64", "data.num_surface_samples=64",
                       "model.rff.num_frequencies=16", "model.net.width=16", "model.net.depth=1",
                       "evaluation.mass_samples=2048", "evaluation.ucd_samples=2000",
                       "evaluation.mesh.resolution=24", "evaluation.mesh.method=phase",
                       "data.normalize=auto"])  # the cap's own frame (preset=cpu would normalise it): pictures
    train(cfg, out_dir=tmp_path)                  # are drawn in model coordinates, compared with the file's below
    assert {"mesh.png", "target.png"} <= set(drawn) and (tmp_path / "target.png").is_file()
    mesh, target = drawn["mesh.png"], drawn["target.png"]
    assert len(mesh["mesh"].faces) > 0
    # one direction, one cube
    assert mesh["view"] == target["view"]
    np.testing.assert_array_equal(mesh["box"], target["box"])
    # the cube frames the target and Γ (its rim), not whatever was extracted: centred on both point sets'
    # bounding box, half-side 0.55 × their largest extent
    cap = spherical_cap()
    pts = np.concatenate([cap.vertices, *mesh_boundary_loops(cap.vertices, cap.faces)])
    half = 0.55 * float((pts.max(0) - pts.min(0)).max())
    np.testing.assert_allclose(mesh["box"].mean(1), 0.5 * (pts.max(0) + pts.min(0)), atol=1e-6)
    np.testing.assert_allclose(mesh["box"][:, 1] - mesh["box"][:, 0], 2 * half, rtol=1e-6)
    # both drawn along the current: for ω ≈ α that is against the target's own (Stokes) normals
    from deepcurrents.models.loading import load_module

    current = load_module(tmp_path / "checkpoints" / "last.ckpt").current
    for picture in (mesh, target):
        m = picture["mesh"]
        assert flux_sign(current, np.asarray(m.vertices), np.asarray(m.faces)) > 0
    drawn_target = target["mesh"]
    assert isinstance(drawn_target, trimesh.Trimesh) and len(drawn_target.faces) == len(cap.faces)
    outward = (drawn_target.face_normals * drawn_target.triangles_center).sum(1)
    assert (outward < 0).all()  # the cap's outward normals, reversed


def test_the_framed_cube_holds_every_point_of_a_lopsided_set():
    """Dense toes and a sparse heel: every point lies inside the cube centre ± radius (the points' mean, the
    former centre, left the heel 0.4 outside it)."""
    rng = np.random.default_rng(0)
    toes = rng.uniform([-0.1, 0.8, -0.1], [0.1, 1.0, 0.1], size=(5000, 3))
    heel = np.array([[0.0, -1.0, 0.0], [0.05, -0.95, 0.0]])
    view = plots.mesh_view([toes, heel])
    lo = np.asarray(view.center) - view.radius
    hi = np.asarray(view.center) + view.radius
    pts = np.vstack([toes, heel])
    assert (pts >= lo).all() and (pts <= hi).all()


def test_a_shape_along_the_view_diagonal_stays_inside_the_picture():
    """A long rod from one corner of its framing cube towards the opposite one: at the fixed ×1.6 zoom its ends
    projected outside the axes' frame, where matplotlib cuts them off (a generated hand's wrist cap was cut so);
    ``mesh_view`` now chooses the zoom from the framed points' projected extent (one zoom for all the pictures
    that share the view), so every vertex projects inside the frame, while a compact shape keeps the full zoom."""
    from mpl_toolkits.mplot3d import proj3d

    def outside(fig, points):
        ax = fig.axes[0]
        xs, ys, _ = proj3d.proj_transform(points[:, 0], points[:, 1], points[:, 2], ax.get_proj())
        (x0, y0), (x1, y1) = ax.viewLim.get_points()
        return int(((xs < x0) | (xs > x1) | (ys < y0) | (ys > y1)).sum())

    for direction in ([1.0, 1.0, 1.0], [1.0, -1.0, 1.0], [-1.0, 1.0, 1.0], [1.0, 1.0, -1.0]):
        ends = np.array([direction, [-c for c in direction]])
        rod = trimesh.creation.cylinder(radius=0.08, segment=ends)
        fig = plots.plot_mesh(rod, None, None)
        assert outside(fig, np.asarray(rod.vertices)) == 0, direction
        plt.close(fig)
    fig = plots.plot_mesh(rod, None, None)  # the fixed zoom, as before, for contrast: the rod's ends overrun
    fig.axes[0].set_box_aspect((1, 1, 1), zoom=plots.FRAME_ZOOM)
    overrun = outside(fig, np.asarray(rod.vertices))
    plt.close(fig)
    blob = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    fig = plots.plot_mesh(blob, None, None)
    ax = fig.axes[0]
    assert plots.fitting_zoom(ax, np.asarray(blob.vertices)) == plots.FRAME_ZOOM  # a compact shape: the full zoom
    plt.close(fig)
    assert overrun > 0


def test_a_family_picture_draws_each_mesh_above_its_target_framed_and_coloured_alike(tmp_path):
    """plot_mesh_pairs: a learned mesh and its target as a file has it (faces the other way round: the current's
    mesh runs against the target's right-hand normal) give the same picture below the titles, the target
    turned over and framed with the mesh; a third pair in a row of two starts a second row of pairs."""
    cap = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    cap = trimesh.Trimesh(cap.vertices, cap.faces[cap.triangles_center[:, 2] > 0.05])
    loops = mesh_boundary_loops(cap.vertices, cap.faces)
    target = trimesh.Trimesh(cap.vertices, cap.faces[:, ::-1])
    image = plots.plot_mesh_pairs([cap], [target], [loops], tmp_path / "pair.png", titles=["0: cap"], size=2.0)
    h = image.shape[0] // 2
    assert image.shape[1] == h and (tmp_path / "pair.png").is_file()
    body = slice(h // 4, h)  # below the titles
    assert np.array_equal(image[:h][body], image[h:][body])
    assert (image[:h][body, :, :3] < 200).any()  # not blank
    small = trimesh.Trimesh(cap.vertices * 0.5, cap.faces)
    image = plots.plot_mesh_pairs([cap, cap, small], [target] * 3, [loops, loops, [lp * 0.5 for lp in loops]],
                                  tmp_path / "pairs.png", titles=["a", "b", "c"], ncols=2, size=2.0)
    assert image.shape[0] == 2 * image.shape[1]  # two rows of two pairs: four tiles high, two wide
    assert (image[2 * h:, h:, :3] == 255).all()  # the second row's second column is blank
