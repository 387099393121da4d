"""Pictures without a display (matplotlib, Agg): meshes with their boundary, a grid of mesh pictures
(families: training shapes, interpolations, paper Fig. 6), 2D currents."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import matplotlib
import matplotlib.figure
import matplotlib.pyplot as plt
import numpy as np
import trimesh
from mpl_toolkits.mplot3d import proj3d
from mpl_toolkits.mplot3d.art3d import Poly3DCollection


def normal_colors(normals: np.ndarray) -> np.ndarray:
    """The paper's colouring: the (unit) current direction mapped to RGB, (n + 1) / 2. (N, 3) → (N, 3)."""
    n = normals / np.linalg.norm(normals, axis=-1, keepdims=True).clip(1e-12)
    return np.clip(0.5 * (n + 1.0), 0.0, 1.0)


def figure_pixels(fig, path: str | Path | None = None) -> np.ndarray:
    """A matplotlib figure as pixels (H, W, 4) uint8 RGBA, written to ``path`` too if given; the figure is
    closed."""
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba()).copy()
    if path is not None:
        fig.savefig(path)
    plt.close(fig)
    return image


def _finish(fig, ax, title: str | None, path: str | Path | None):
    """Title, tight layout, and for a ``path`` the file written and the figure closed. → the figure."""
    if title:
        ax.set_title(title)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path)
        plt.close(fig)
    return fig


FRAME_ZOOM = 1.6  # the axes cube is hidden: let the shape fill the frame


@dataclass(frozen=True)
class MeshView:
    """What a ``plot_mesh`` picture shows: the view direction (matplotlib's elevation and azimuth in degrees,
    z up) and the cube ``center ± radius`` it frames. Pictures meant to be compared share one."""

    elev: float = 25.0
    azim: float = 35.0
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 1.0
    zoom: float = FRAME_ZOOM  # of the hidden axes cube (less where the framed points would overrun the frame)


def mesh_view(points: Sequence[np.ndarray], elev: float = 25.0, azim: float = 35.0, margin: float = 1.0) -> MeshView:
    """The view framing point sets (each (N_i, 3): a mesh's vertices, Γ's loops, a target): centred on
    their bounding box, half-side 0.55 × its largest extent × ``margin``, so the cube holds every point (the
    mean of the points, the former centre, leans to where they are dense: a foot's toes pushed its heel out
    of the picture)."""
    pts = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in points])
    if len(pts) == 0:
        return MeshView(elev, azim)
    low, high = pts.min(0), pts.max(0)
    radius = 0.55 * float((high - low).max()) * margin
    view = MeshView(float(elev), float(azim), tuple(float(c) for c in 0.5 * (low + high)), radius)
    fig = matplotlib.figure.Figure(figsize=(3, 3))  # a throwaway axes with the view, to project the points
    ax = fig.add_subplot(projection="3d")
    _frame(ax, view)
    return replace(view, zoom=fitting_zoom(ax, pts))


def _frame(ax, view: MeshView) -> None:
    """The axes' cube centre ± radius and view direction (not yet the zoom)."""
    c, r = view.center, view.radius
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.view_init(elev=view.elev, azim=view.azim)


def plot_mesh(
    mesh: trimesh.Trimesh,
    loops: list[np.ndarray] | None = None,
    path: str | Path | None = None,
    title: str | None = None,
    elev: float = 25.0,
    azim: float = 35.0,
    size: float = 5.0,
    max_faces: int = 60000,
    view: MeshView | None = None,
):
    """A shaded mesh coloured by its normals (the current's direction) with Γ drawn in black. → Figure.

    ``view``: the view direction and framing (``mesh_view``); default: ``elev``/``azim``, framed on the
    mesh's vertices and Γ.
    """
    fig = plt.figure(figsize=(size, size), dpi=120)
    ax = fig.add_subplot(projection="3d")
    if len(mesh.faces):
        m = mesh
        if len(m.faces) > max_faces:  # keep pictures quick: the eye does not need every face
            keep = np.random.default_rng(0).choice(len(m.faces), max_faces, replace=False)
            m = trimesh.Trimesh(m.vertices, m.faces[keep], process=False)
        light = np.array([0.3, 0.4, 0.85])
        light /= np.linalg.norm(light)
        shade = 0.55 + 0.45 * np.abs(m.face_normals @ light)
        colors = normal_colors(m.face_normals) * shade[:, None]
        ax.add_collection3d(Poly3DCollection(m.triangles, facecolors=colors, edgecolors="none"))
    for loop in loops or []:
        closed = np.concatenate([loop, loop[:1]])
        ax.plot(*closed.T, color="black", linewidth=1.5)
    if view is None:
        pts = ([np.asarray(mesh.vertices)] if len(mesh.vertices) else []) + list(loops or [])
        view = mesh_view(pts, elev, azim) if pts else None
    if view is not None:
        _frame(ax, view)
    else:
        ax.view_init(elev=elev, azim=azim)
    ax.set_box_aspect((1, 1, 1), zoom=view.zoom if view is not None else FRAME_ZOOM)
    ax.set_axis_off()
    return _finish(fig, ax, title, path)


def fitting_zoom(ax, points: np.ndarray, fill: float = 0.92) -> float:
    """The axes cube's zoom that lets the shape fill the frame: ``FRAME_ZOOM``, or less where the points
    (N, 3), projected in the axes' view, would overrun ``fill`` of the frame's half-width (a shape along the
    view's diagonal; projected coordinates scale with the zoom)."""
    ax.set_box_aspect((1, 1, 1), zoom=1.0)
    if len(points) > 20000:  # the extent, not every vertex
        points = points[np.random.default_rng(0).choice(len(points), 20000, replace=False)]
    xs, ys, _ = proj3d.proj_transform(points[:, 0], points[:, 1], points[:, 2], ax.get_proj())
    (x0, y0), (x1, y1) = ax.viewLim.get_points()
    half = 0.5 * min(x1 - x0, y1 - y0)
    extent = max(np.abs(xs - 0.5 * (x0 + x1)).max(), np.abs(ys - 0.5 * (y0 + y1)).max())
    return float(min(FRAME_ZOOM, fill * half / extent)) if extent > 0 else FRAME_ZOOM


def _tile(tiles: Sequence[np.ndarray | None], ncols: int, path: str | Path) -> np.ndarray:
    """Pictures (H, W, 4) laid out row by row, ``ncols`` per row, None a blank; written as a PNG. → the image."""
    first = next(t for t in tiles if t is not None)
    h, w = first.shape[:2]
    nrows = int(np.ceil(len(tiles) / ncols))
    image = np.full((nrows * h, ncols * w, 4), 255, dtype=np.uint8)
    for i, tile in enumerate(tiles):
        if tile is not None:
            r, c = divmod(i, ncols)
            image[r * h:(r + 1) * h, c * w:(c + 1) * w] = tile[:h, :w]
    plt.imsave(path, image)
    return image


def plot_mesh_grid(
    meshes: Sequence[trimesh.Trimesh],
    loops: Sequence[Sequence[np.ndarray]] | None,
    path: str | Path,
    titles: Sequence[str] | None = None,
    ncols: int | None = None,
    size: float = 3.0,
    elev: float = 25.0,
    azim: float = 35.0,
) -> np.ndarray:
    """Draws each mesh with ``plot_mesh`` (normal colours, Γ in black) and tiles the pictures row by row,
    ``ncols`` per row (default: as square as possible). Writes a PNG at ``path``. → the image (H, W, 4)."""
    n = len(meshes)
    if n == 0:
        raise ValueError("plot_mesh_grid needs at least one mesh")
    ncols = ncols or int(np.ceil(np.sqrt(n)))
    tiles = [figure_pixels(plot_mesh(mesh, None if loops is None else list(loops[i]), None,
                                     title=None if titles is None else titles[i], elev=elev, azim=azim, size=size))
             for i, mesh in enumerate(meshes)]
    return _tile(tiles, ncols, path)


def plot_mesh_pairs(
    meshes: Sequence[trimesh.Trimesh],
    targets: Sequence[trimesh.Trimesh],
    loops: Sequence[Sequence[np.ndarray]],
    path: str | Path,
    titles: Sequence[str],
    ncols: int = 6,
    size: float = 3.0,
) -> np.ndarray:
    """Each learned mesh above its target, the two framed alike (one ``mesh_view`` of both and Γ), up to
    ``ncols`` pairs per row of pairs; Γ (``loops[i]``) drawn on both. The target is drawn with its faces turned
    over: a current's mesh is oriented along ω, against the right-hand normal of Γ taken from the target's
    faces, so the colours (the normal's direction) then agree. Writes a PNG at ``path``. → the image."""
    if not meshes or len(meshes) != len(targets):
        raise ValueError("plot_mesh_pairs needs as many targets as meshes, at least one")
    ncols = min(ncols, len(meshes))
    tiles: list[np.ndarray | None] = []
    for start in range(0, len(meshes), ncols):
        top, bottom = [], []
        for i in range(start, min(start + ncols, len(meshes))):
            pts = [np.asarray(m.vertices) for m in (meshes[i], targets[i]) if len(m.vertices)] + list(loops[i])
            view = mesh_view(pts)
            top.append(figure_pixels(plot_mesh(meshes[i], list(loops[i]), title=titles[i], size=size, view=view)))
            turned = trimesh.Trimesh(targets[i].vertices, np.asarray(targets[i].faces)[:, ::-1], process=False)
            bottom.append(figure_pixels(plot_mesh(turned, list(loops[i]), title="target", size=size, view=view)))
        pad = [None] * (ncols - len(top))
        tiles += top + pad + bottom + pad
    return _tile(tiles, ncols, path)


def plot_current_2d(
    f_grid: np.ndarray,
    alpha_grid: np.ndarray | None,
    curves: list[np.ndarray],
    poles: np.ndarray,
    signs: np.ndarray,
    path: str | Path | None = None,
    title: str | None = None,
    metric_grid: np.ndarray | None = None,
    grid_extent: float = 1.0,
):
    """Paper Fig. 3: f as a density plot, α as arrows, the metric as ellipses, the extracted curve, the
    boundary points.

    f_grid (R, R) on [-1, 1]² with axis 0 = x; alpha_grid (r, r, 2) and metric_grid (r, r, 2, 2) (the
    matrices B_x, or None) on a coarser grid whose nodes span [-grid_extent, grid_extent]².
    """
    fig, ax = plt.subplots(figsize=(5, 5), dpi=120)
    ax.imshow(f_grid.T, origin="lower", extent=(-1, 1, -1, 1), cmap="coolwarm")
    if metric_grid is not None:
        _metric_ellipses(ax, metric_grid, grid_extent)
    if alpha_grid is not None:
        r = alpha_grid.shape[0]
        g = np.linspace(-grid_extent, grid_extent, r)
        gx, gy = np.meshgrid(g, g, indexing="ij")
        a = alpha_grid / np.linalg.norm(alpha_grid, axis=-1, keepdims=True).clip(1e-12)
        ax.quiver(gx, gy, a[..., 0], a[..., 1], color="0.25", scale=2.2 * r, width=0.003)
    for c in curves:
        ax.plot(c[:, 0], c[:, 1], color="black", linewidth=2)
    ax.scatter(poles[:, 0], poles[:, 1], c=np.where(signs > 0, "tab:red", "tab:blue"), s=40, zorder=3)
    ax.set_xlim(-1, 1)
    ax.set_ylim(-1, 1)
    ax.set_aspect("equal")
    return _finish(fig, ax, title, path)


def _metric_ellipses(ax, metric_grid: np.ndarray, extent: float) -> None:
    """Paper Fig. 3d: each B_x (r, r, 2, 2) as an ellipse along its eigenvectors, semi-axes ∝ eigenvalues
    (not to scale: the largest fills 0.45 of a cell; a zero eigenvalue still shows as a thin line)."""
    from matplotlib.collections import EllipseCollection

    r = metric_grid.shape[0]
    b = metric_grid.reshape(-1, 2, 2)
    sym = 0.5 * (b + np.swapaxes(b, 1, 2))
    vals, vecs = np.linalg.eigh(sym)  # ascending: column 1 is the major axis
    vals = np.abs(vals)
    top = vals.max() if vals.size and vals.max() > 0 else 1.0
    cell = 2.0 * extent / max(r - 1, 1)
    major = 0.9 * cell * vals[:, 1] / top
    minor = np.maximum(0.9 * cell * vals[:, 0] / top, 0.06 * cell)
    angles = np.degrees(np.arctan2(vecs[:, 1, 1], vecs[:, 0, 1]))
    g = np.linspace(-extent, extent, r)
    centres = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    keep = major > 0
    ax.add_collection(EllipseCollection(
        major[keep], minor[keep], angles[keep], units="xy", offsets=centres[keep],
        offset_transform=ax.transData, facecolors="none", edgecolors="0.15", linewidths=0.6,
    ))
