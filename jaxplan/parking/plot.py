"""Picture of one park-out: obstacles, the grid the planner saw, every move and the car's outline."""

from __future__ import annotations

import numpy as np

from jaxplan.parking.frames import SlotFrame, axle_to_centre
from jaxplan.parking.scene_file import car_outline

IDENTITY = SlotFrame(origin=(0.0, 0.0), heading=0.0, sign=1)


def plot_parkout(
    ax, polygons, result, vehicle, config, frame: SlotFrame = IDENTITY, cells=None, stop_y=None, title=None
):
    """Draw one park-out on a matplotlib axis, in the world frame of ``frame``.

    Args:
        polygons: obstacle outlines in the world, a list of ``(n_i, 2)``.
        result: one scene's ``ParkoutResult`` (slot-frame rear-axle poses).
        cells: optional ``(rows, cols)`` blocked cells of the grid (slot frame, pose 0).
        stop_y: optional stop line ``y = d`` of the slot frame, drawn dashed.
    """
    from matplotlib.patches import Polygon as MplPolygon

    h = config.cell
    if cells is not None:
        c = np.asarray(cells, bool)
        u = config.x_min + h * np.arange(config.cols + 1)
        v = config.y_min + h * np.arange(config.rows + 1)
        uu, vv = np.meshgrid(u, v)
        w = frame.to_world_xy(np.stack([uu, vv], -1))
        ax.pcolormesh(
            w[..., 0],
            w[..., 1],
            np.ma.masked_where(~c, c.astype(float)),
            cmap="Greys",
            vmin=0,
            vmax=2.5,
            shading="flat",
            rasterized=True,
        )
        edge = frame.to_world_xy(np.array([[u[0], v[0]], [u[-1], v[0]], [u[-1], v[-1]], [u[0], v[-1]]]))
        ax.add_patch(
            MplPolygon(
                edge, closed=True, fill=False, ls=":", ec="0.5", lw=0.8, label="grid extent (outside = occupied)"
            )
        )
    for i, p in enumerate(polygons):
        ax.add_patch(
            MplPolygon(
                np.asarray(p), closed=True, fc="0.35", ec="k", lw=0.6, alpha=0.8, label="obstacles" if i == 0 else None
            )
        )
    poses, valid, gear = (np.asarray(a) for a in (result.poses, result.valid, result.gear))
    pts = [frame.to_world_xy(np.zeros(2))]
    first = {1: True, -1: True}
    for m in range(len(gear)):
        if gear[m] == 0:
            continue
        q = axle_to_centre(frame.to_world_pose(poses[m][valid[m]]), vehicle)
        col = "C0" if gear[m] > 0 else "C3"
        ax.plot(
            q[:, 0],
            q[:, 1],
            color=col,
            lw=1.8,
            label=("forward" if gear[m] > 0 else "reverse") if first[int(gear[m])] else None,
        )
        first[int(gear[m])] = False
        for j in range(0, len(q), 10):
            ax.add_patch(MplPolygon(car_outline(q[j], vehicle), closed=True, fill=False, ec=col, lw=0.3, alpha=0.5))
        ax.add_patch(MplPolygon(car_outline(q[-1], vehicle), closed=True, fill=False, ec=col, lw=1.0))
        pts.append(q[:, :2])
    start = axle_to_centre(frame.to_world_pose(poses[0, 0] if gear[0] != 0 else np.asarray(result.final_pose)), vehicle)
    ax.add_patch(MplPolygon(car_outline(start, vehicle), closed=True, fill=False, ec="k", lw=1.6, label="start"))
    if bool(result.success):
        fin = axle_to_centre(frame.to_world_pose(np.asarray(result.final_pose)), vehicle)
        ax.add_patch(MplPolygon(car_outline(fin, vehicle), closed=True, fill=False, ec="g", lw=1.6, label="out"))
    if stop_y is not None:
        line = frame.to_world_xy(np.array([[config.x_min, stop_y], [config.x_min + h * config.cols, stop_y]]))
        ax.plot(line[:, 0], line[:, 1], "g--", lw=0.8, label="stop line (rear axle)")
    # the slot's surroundings (in the slot frame) and every driven point
    box = np.array([[-8.0, -2.5], [13.0, -2.5], [13.0, 6.5], [-8.0, 6.5]])
    pts.append(frame.to_world_xy(box))
    allp = np.concatenate([np.atleast_2d(p) for p in pts])
    lo, hi = allp.min(0) - 1.0, allp.max(0) + 1.0
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    n = int(np.sum(gear != 0))
    ax.set_title(title or f"park-out: {'out' if bool(result.success) else 'FAILED'}, {n} moves")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    return ax


def save_plot(path, *args, figsize=(10.5, 5.5), **kw):
    """``plot_parkout`` into a PNG file."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=figsize)
    plot_parkout(ax, *args, **kw)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
