"""Matplotlib drawing of scenes: the road, goal and route (``draw_scene``) and boxes
(``draw_box``), shared by the planners' and the simulator's pictures."""

from __future__ import annotations

import numpy as np


def draw_scene(ax, scene):
    """Draw a (numpy, unbatched) ``Scene``'s drivable area, goal region and route on ``ax``."""
    import matplotlib.patches as mpatches

    drv, ok = np.asarray(scene.drivable), np.asarray(scene.drivable_valid)
    for p, m in zip(drv, ok):
        if m.any():
            ax.add_patch(mpatches.Polygon(p[m], closed=True, fc="0.9", ec="0.6", lw=0.5, zorder=0))
    g = scene.goal
    for p, m in zip(np.asarray(g.region), np.asarray(g.region_valid)):
        if m.any():
            ax.add_patch(
                mpatches.Polygon(p[m], closed=True, fc=(0.2, 0.7, 0.2, 0.25), ec="g", lw=1, zorder=1, label="goal")
            )
    r = np.asarray(scene.route.xy)
    ax.plot(r[:, 0], r[:, 1], "--", color="0.4", lw=0.8, label="route", zorder=2)


def draw_box(ax, b, **kw):
    """Draw the box ``b = [x, y, length, width, heading]`` on ``ax`` as a polygon (``kw``: its
    matplotlib style)."""
    import matplotlib.patches as mpatches

    x, y, L, W, h = b
    c, s = np.cos(h), np.sin(h)
    corners = np.array(
        [
            [x + c * dx - s * dy, y + s * dx + c * dy]
            for dx, dy in ((L / 2, W / 2), (-L / 2, W / 2), (-L / 2, -W / 2), (L / 2, -W / 2))
        ]
    )
    ax.add_patch(mpatches.Polygon(corners, closed=True, **kw))
