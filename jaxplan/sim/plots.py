"""Bird's-eye pictures of a drive: road, route, goal, obstacles, the driven path (coloured
by speed), where it collided or left the road; optionally an animation (GIF)."""

from __future__ import annotations

import numpy as np

from jaxplan.scenarios.draw import draw_box, draw_scene


def _axes_box(ax, xy_list, margin=15.0):
    pts = np.concatenate([p.reshape(-1, 2) for p in xy_list if p.size])
    lo, hi = pts.min(0) - margin, pts.max(0) + margin
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])


def plot_drive(path: str, scene, row: dict, log: dict, vehicle, title: str) -> str:
    """Write one drive's bird's-eye PNG.

    Args:
        scene: the unbatched numpy ``Scene``.
        row: the drive's metrics (``overlap.first_step``, ``offroad.first_step``, ``goal.step``, ...).
        log: numpy arrays ``t, x, y, heading, v, valid`` of the drive (box centres).
    """
    import matplotlib.pyplot as plt

    n = int(np.sum(log["valid"]))
    xy = np.stack([log["x"][:n], log["y"][:n]], -1)
    fig, ax = plt.subplots(figsize=(9, 6))
    draw_scene(ax, scene)
    obs = scene.obstacles
    K = np.asarray(obs.boxes).shape[0]
    boxes, valid = np.asarray(obs.boxes), np.asarray(obs.valid)
    static = np.asarray(obs.static)
    T = boxes.shape[1]
    for k in range(K):
        if static[k] and valid[k].any():
            draw_box(ax, boxes[k, np.argmax(valid[k])], fc="0.3", ec="k", zorder=3)
            continue
        steps = np.arange(0, min(n, T))
        steps = steps[valid[k, steps]] if len(steps) else steps
        if len(steps):
            ax.plot(boxes[k, steps, 0], boxes[k, steps, 1], "-", color="tab:blue", lw=0.6, alpha=0.6, zorder=3)
            draw_box(ax, boxes[k, steps[0]], fc=(0.12, 0.47, 0.71, 0.25), ec="tab:blue", lw=0.6, zorder=3)
    sc = ax.scatter(xy[:, 0], xy[:, 1], c=log["v"][:n], cmap="viridis", s=6, zorder=5)
    fig.colorbar(sc, ax=ax, label="speed (m/s)")
    draw_box(
        ax, [xy[0, 0], xy[0, 1], vehicle.length, vehicle.width, log["heading"][0]], fc="none", ec="k", lw=1, zorder=6
    )
    marks = []
    k = int(row.get("overlap.first_step", -1))
    if k >= 0:
        draw_box(
            ax,
            [log["x"][k], log["y"][k], vehicle.length, vehicle.width, log["heading"][k]],
            fc="red",
            ec="darkred",
            alpha=0.8,
            zorder=7,
        )
        o = int(row.get("overlap.obstacle", -1))
        if o >= 0:
            draw_box(
                ax,
                boxes[o, min(k, T - 1)] if not static[o] else boxes[o, np.argmax(valid[o])],
                fc="orange",
                ec="darkred",
                alpha=0.8,
                zorder=7,
            )
        marks.append(f"collision at t = {log['t'][k]:.1f} s" + (" (at fault)" if row.get("overlap.at_fault") else ""))
    k = int(row.get("offroad.first_step", -1))
    if k >= 0:
        ax.plot(log["x"][k], log["y"][k], "x", color="m", ms=10, mew=2, zorder=8)
        marks.append(f"off road at t = {log['t'][k]:.1f} s")
    k = int(row.get("goal.step", -1))
    if k >= 0:
        ax.plot(log["x"][k], log["y"][k], "*", color="g", ms=14, zorder=8)
        marks.append(f"goal at t = {log['t'][k]:.1f} s")
    _axes_box(ax, [xy, np.asarray(scene.goal.region)[np.asarray(scene.goal.region_valid)]])
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title + ("\n" + "; ".join(marks) if marks else ""), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def animate_drive(path: str, scene, log: dict, vehicle, title: str, fps: int = 10) -> str:
    """Write a GIF of the drive (matplotlib's animation writer, Pillow)."""
    import matplotlib.pyplot as plt
    from matplotlib import animation

    n = int(np.sum(log["valid"]))
    xy = np.stack([log["x"][:n], log["y"][:n]], -1)
    boxes, valid = np.asarray(scene.obstacles.boxes), np.asarray(scene.obstacles.valid)
    static = np.asarray(scene.obstacles.static)
    T = boxes.shape[1]
    fig, ax = plt.subplots(figsize=(8, 5))

    def frame(i):
        ax.clear()
        draw_scene(ax, scene)
        for k in range(boxes.shape[0]):
            j = np.argmax(valid[k]) if static[k] else min(i, T - 1)
            if (static[k] and valid[k].any()) or (i < T and valid[k, j]):
                draw_box(ax, boxes[k, j], fc="0.3" if static[k] else "tab:blue", ec="k", alpha=0.7, zorder=3)
        ax.plot(xy[: i + 1, 0], xy[: i + 1, 1], "-", color="tab:green", lw=1.5, zorder=4)
        draw_box(
            ax, [xy[i, 0], xy[i, 1], vehicle.length, vehicle.width, log["heading"][i]], fc="tab:red", ec="k", zorder=5
        )
        c = xy[i]
        ax.set_xlim(c[0] - 40, c[0] + 40)
        ax.set_ylim(c[1] - 25, c[1] + 25)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(f"{title}  t = {log['t'][i]:.1f} s  v = {log['v'][i]:.1f} m/s", fontsize=9)

    anim = animation.FuncAnimation(fig, frame, frames=n, interval=1000 / fps)
    anim.save(path, writer=animation.PillowWriter(fps=fps))
    plt.close(fig)
    return path
