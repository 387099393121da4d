"""Part borders of the human-part generator, before (``border=faces``: along mesh edges, each face to its
dominant bone) and after (``border=smooth``: along the level set 1/2 of the part's skinning weight, inside
triangles): pictures of a wrist and a neck, and numbers for every category's borders.

    python benchmarks/part_borders.py [--bodies 2] [--out docs/gallery/part_borders.png]

Numbers per category and cut: border loops, mean |turning angle| between consecutive border segments
(a sawtooth turns by tens of degrees at every vertex, a smooth curve by 360°/n on average), border length,
and the smallest triangle angle of the part.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from deepcurrents.data.human_parts import CATEGORIES
from deepcurrents.data.human_parts_builder import anny_model, anny_parts
from deepcurrents.data.targets import mesh_boundary_loops


def turning_degrees(loop: np.ndarray) -> np.ndarray:
    """|Turning angle| at each vertex of a closed polyline, in degrees. (N, 3) → (N,)."""
    a = loop - np.roll(loop, 1, axis=0)
    b = np.roll(loop, -1, axis=0) - loop
    cos = (a * b).sum(1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)).clip(1e-15)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def min_angles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The smallest angle of each triangle, in degrees. → (F,)."""
    tri = vertices[faces]
    out = []
    for k in range(3):
        a, b = tri[:, (k + 1) % 3] - tri[:, k], tri[:, (k + 2) % 3] - tri[:, k]
        cos = (a * b).sum(1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)).clip(1e-15)
        out.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.min(out, axis=0)


def crop_near(vertices: np.ndarray, faces: np.ndarray, loop: np.ndarray, radius: float) -> np.ndarray:
    """Faces with a vertex within ``radius`` of the loop's vertices."""
    d = np.linalg.norm(vertices[:, None, :] - loop[None, :, :], axis=2).min(1)
    return faces[(d[faces] < radius).any(1)]


def draw(ax, vertices: np.ndarray, faces: np.ndarray, loop: np.ndarray, title: str, view: tuple[float, float]):
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True).clip(1e-15)
    light = np.array([0.3, 0.4, 0.85]) / np.linalg.norm([0.3, 0.4, 0.85])
    shade = 0.45 + 0.5 * np.abs(normals @ light)
    ax.add_collection3d(Poly3DCollection(tri, facecolors=np.c_[shade, shade, shade * 1.05].clip(0, 1),
                                         edgecolors=(0.25, 0.25, 0.3), linewidths=0.25))
    closed = np.concatenate([loop, loop[:1]])
    ax.plot(*closed.T, color="crimson", linewidth=2.0)
    c, r = loop.mean(0), 0.6 * (loop.max(0) - loop.min(0)).max()
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.view_init(elev=view[0], azim=view[1])
    ax.set_box_aspect((1, 1, 1), zoom=1.3)
    ax.set_axis_off()
    ax.set_title(title, fontsize=9)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bodies", type=int, default=2)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--out", default="docs/gallery/part_borders.png")
    args = parser.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    model = anny_model()
    parts = {b: anny_parts(args.bodies, args.seed, model=model, border=b) for b in ("faces", "smooth")}
    print(f"{'category':9s} {'cut':7s} loops  mean|turn|°  border length  min angle°  F")
    for c in CATEGORIES:
        for b in ("faces", "smooth"):
            verts, faces, _ = parts[b][c]
            loops = mesh_boundary_loops(verts[0], faces)
            turn = np.concatenate([turning_degrees(loop) for loop in loops])
            length = sum(float(np.linalg.norm(loop - np.roll(loop, 1, 0), axis=1).sum()) for loop in loops)
            print(f"{c:9s} {b:7s} {len(loops):5d}  {turn.mean():11.1f}  {length:13.3f}  "
                  f"{min_angles(verts[0], faces).min():10.2f}  {len(faces)}")
    fig = plt.figure(figsize=(8, 8), dpi=100)
    for row, (category, which, view) in enumerate([("hands", "wrist", (10.0, -60.0)), ("heads", "neck", (-30.0, 0.0))]):
        for col, b in enumerate(("faces", "smooth")):
            verts, faces, _ = parts[b][category]
            v = verts[0]
            loops = mesh_boundary_loops(v, faces)
            # the wrist is the hand's only loop; the neck is the head's longest one (eyes and mouth are inner)
            loop = max(loops, key=lambda lp: float(np.linalg.norm(lp - np.roll(lp, 1, 0), axis=1).sum()))
            size = float((loop.max(0) - loop.min(0)).max())
            label = "before: mesh edges, dominant bone" if b == "faces" else "after: skinning-weight level set"
            draw(fig.add_subplot(2, 2, 2 * row + col + 1, projection="3d"), v,
                 crop_near(v, faces, loop, 0.25 * size), loop, f"{which}, {label}", view)
    fig.tight_layout()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out)
    print("wrote", args.out)


if __name__ == "__main__":
    main()
