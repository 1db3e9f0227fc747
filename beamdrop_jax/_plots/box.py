"""A box housing at impact, in 3D: the box in its attitude on the ground, the board inside it, its screws coloured
by the normal velocity jump each receives, the struck point and the impulse."""

import math

import numpy as np

from .._impact.box import box_attitude
from .._scene.containers import board_ends


def _edges(half):
    """The 12 edges of a box with half-extents `half`, as pairs of body points."""
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    return [(corners[i], corners[j]) for i in range(8) for j in range(i + 1, 8)
            if np.sum(np.abs(corners[i] - corners[j]) > 0) == 1]


def plot_box(scene, response=None, *, ax=None):
    """The box housing of `scene` (`Housing.depth`) at the instant of impact, G straight above the ground at its
    lowest point's height: the board (its outline, in the box's plane of motion along `Placement.angle`, its width
    along e3), a plate's screws (coloured by `response.mount_jumps`, m/s, when a `simulate` response is given),
    the struck point and, with a response of a tilted drop, the direction of the 3D impulse. Axes: x and z
    horizontal (z out of the plane of motion), y up."""
    import matplotlib.pyplot as plt

    if not scene.housing.is_box:
        raise ValueError("plot_box draws a box housing: give Housing.depth (m); plot_scene draws a plane section")
    h, d, p = scene.housing, scene.drop, scene.placement
    half = np.array([float(h.width), float(h.height), float(h.depth)]) / 2
    R = np.asarray(box_attitude(float(d.orientation), float(d.tilt)))
    lift = np.sum(np.abs(R[1]) * half)  # G's height when the lowest point touches the ground
    G = np.array([0.0, lift, 0.0])
    to_plot = lambda pts: np.asarray(pts)[..., [0, 2, 1]] * 1e3  # noqa: E731 - (x, y up, z) -> (x, z, y up), mm
    world = lambda q: G + np.asarray(q) @ R.T  # noqa: E731 - body points -> ground frame
    if ax is None:
        fig = plt.figure(figsize=(7.5, 6.0), layout="constrained")
        ax = fig.add_subplot(projection="3d")
    fig = ax.figure
    reach = 1e3 * float(np.linalg.norm(half)) * 1.1
    ground = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * reach
    ax.plot_trisurf(ground[:, 0], ground[:, 1], np.zeros(4), color="0.85", alpha=0.35, linewidth=0)
    for a, b in _edges(half):
        seg = to_plot(np.stack([world(a), world(b)]))
        ax.plot(*seg.T, color="0.35", linewidth=1.0)
    # The board: its centre line from end A to end B in the plane of motion, its width along e3.
    ends = np.asarray(board_ends(p, scene.board.length), float)
    z0, bw = float(p.depth_offset), float(scene.board.width)
    outline = [np.append(ends[0], z0 - bw / 2), np.append(ends[1], z0 - bw / 2), np.append(ends[1], z0 + bw / 2),
               np.append(ends[0], z0 + bw / 2)]
    poly = to_plot(np.array([world(q) for q in outline + outline[:1]]))
    ax.plot(*poly.T, color="tab:green", linewidth=2.0, label="board")
    ax.plot_trisurf(poly[:4, 0], poly[:4, 1], poly[:4, 2], color="tab:green", alpha=0.25, linewidth=0)
    mounts = getattr(scene.board, "mounts", None)
    if mounts is not None:
        axis = (ends[1] - ends[0]) / float(scene.board.length)
        body = np.array([np.append(ends[0] + x * axis, z0 + y) for x, y in np.asarray(mounts, float)])
        pts = to_plot(np.array([world(q) for q in body]))
        jumps = None if response is None or response.mount_jumps is None else np.asarray(response.mount_jumps)
        colours = dict(c="k") if jumps is None else dict(c=jumps, cmap="coolwarm")
        art = ax.scatter(*pts.T, s=40, depthshade=False, edgecolors="k", label="screws", zorder=5, **colours)
        if jumps is not None:
            fig.colorbar(art, ax=ax, shrink=0.6, pad=0.08, label="screw's normal velocity jump (m/s)")
    struck = None
    if response is not None and getattr(response, "box", None) is not None:
        struck = np.asarray(response.box.attitude).T @ np.asarray(response.box.r)
    else:
        struck = np.where(np.abs(R[1]) < 64 * np.finfo(float).eps, 0.0, -np.sign(R[1]) * half)
    s = to_plot(world(struck))
    ax.scatter(*s, color="tab:red", s=70, marker="*", depthshade=False, label="struck point", zorder=6)
    ax.scatter(*to_plot(G), color="k", s=25, marker="o", depthshade=False, label="G")
    if response is not None and getattr(response, "box", None) is not None and float(d.tilt) != 0:
        P = np.asarray(response.box.P)
        arrow = to_plot(P / np.linalg.norm(P)) * 0.5 * float(np.max(half))
        ax.quiver(*s, *arrow, color="tab:red", linewidth=1.5, label="impulse direction")
    ax.set_xlim(-reach, reach)
    ax.set_ylim(-reach, reach)
    ax.set_zlim(0, reach)
    ax.set_box_aspect((2, 2, 1))  # equal scales: x and z span 2 reach, y one
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z, out of the plane (mm)")
    ax.set_zlabel("y, up (mm)")
    ax.view_init(elev=22, azim=-60)
    ax.set_title(f"Box at impact: orientation {math.degrees(float(d.orientation)):.1f} deg, tilt "
                 f"{math.degrees(float(d.tilt)):.1f} deg, from {float(d.height):g} m", fontsize=10)
    ax.legend(loc="upper left", fontsize=8)
    return fig
