"""Pictures of one ``pathspeed`` cycle: the path in its bounds (map and SL views) and the ST
graph with the boundaries, the DP's knots and the executed profile."""

from __future__ import annotations

import functools

import jax
import numpy as np


@functools.cache
def _cycle_fn(planner):
    return jax.jit(planner.speed_plan)


def cycle(planner, scene, ego, step: int = 0, params=None) -> dict:
    """``planner.speed_plan`` of one scene at ``step`` as numpy arrays (jitted once per planner;
    ``params``: default ``planner.init_params()``)."""
    params = planner.init_params() if params is None else params
    return jax.tree_util.tree_map(np.asarray, _cycle_fn(planner)(params, scene, ego, step))


def draw_st(ax, planner, plan, prof) -> None:
    """The ST graph of one plan on ``ax``: blocking boundaries (red), the wall before a
    blockage or the map's end (grey), non-blocking neighbours' ranges (blue) and blind zones
    (cyan), the DP's knots and the executed (QP) profile."""
    sc = plan.scene
    cl = sc.classified
    tf = planner.speed.fine_times()
    front, rear = float(sc.front), float(sc.rear)
    labels = set()

    def lab(name):
        if name in labels:
            return None
        labels.add(name)
        return name

    lo, hi, hit, _ = (np.asarray(a) for a in sc.blocking())
    for k in range(lo.shape[0]):
        if hit[k].any():
            is_wall = k == lo.shape[0] - 1
            ax.fill_between(
                tf,
                np.where(hit[k], lo[k], np.nan),
                np.where(hit[k], np.minimum(hi[k], 400), np.nan),
                color="0.4" if is_wall else "tab:red",
                alpha=0.5,
                label=lab("stop before (blockage / map end)" if is_wall else "blocking"),
            )
    sl, sh, su = np.asarray(cl.side.lower), np.asarray(cl.side.hit), np.asarray(cl.side.upper)
    for k in range(sl.shape[0]):
        if sh[k].any():
            ax.fill_between(
                tf,
                np.where(sh[k], sl[k] - front, np.nan),
                np.where(sh[k], su[k] - rear, np.nan),
                color="tab:blue",
                alpha=0.25,
                label=lab("non-blocking (alongside)"),
            )
            if bool(cl.blind_zone[k]):
                ax.fill_between(
                    tf,
                    np.where(sh[k], sl[k] - planner.speed.blind_back - front, np.nan),
                    np.where(sh[k], sl[k] + planner.speed.blind_front - rear, np.nan),
                    color="tab:cyan",
                    alpha=0.25,
                    hatch="//",
                    label=lab("blind zone"),
                )
    ax.plot(np.asarray(plan.t), np.asarray(plan.s), "ko", ms=4, label="DP knots")
    ax.plot(np.asarray(prof.t), np.asarray(prof.s), "k-", lw=1.5, label="executed (QP)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("s along the path (m, car reference point, from now)")
    top = max(40.0, float(np.asarray(prof.s).max()) + 15.0)
    ax.set_ylim(min(-10.0, float(np.nanmin(np.where(sh, sl - front, 0)))), top)
    ax.legend(fontsize=7, loc="upper left")


def plot_cycle(
    out: str, planner, scene, ego, step: int = 0, title: str = "", params=None, planned: dict | None = None
) -> str:
    """Write ``draw_cycle``'s picture of one cycle to the PNG file ``out``; returns ``out``."""
    import matplotlib.pyplot as plt

    fig = draw_cycle(planner, scene, ego, step, title, params, planned)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


def draw_cycle(planner, scene, ego, step: int = 0, title: str = "", params=None, planned: dict | None = None):
    """The matplotlib figure of one cycle: (1) the map with the obstacles now (blocking for the path:
    red), the path's bounds, the path and the trajectory's points coloured by speed; (2) the
    same in the route's SL frame, titled with the lane decision and the two costs compared;
    (3) the ST graph (``draw_st``), titled with the obstacles' classes.

    Args:
        planner: a ``PathSpeedPlanner``; scene: one (unbatched) ``Scene``;
        ego: the car's ``EgoState``; step: the scene step of the cycle.
        params: the planner's params (default ``planner.init_params()``).
        planned: the cycle's ``planner.speed_plan`` dict when already computed (else ``cycle``).
    """
    import matplotlib.pyplot as plt

    from jaxplan.geometry.frenet import to_cartesian
    from jaxplan.scenarios.draw import draw_box, draw_scene
    from jaxplan.speed.compose import compose_profile

    c = cycle(planner, scene, ego, step, params) if planned is None else planned
    traj = jax.tree_util.tree_map(np.asarray, compose_profile(c["ref"], c["s0"], c["profile"]))
    path = jax.tree_util.tree_map(np.asarray, c["path"])
    pp = None if c["bounds"] is None else jax.tree_util.tree_map(np.asarray, c["bounds"])
    ctx = jax.tree_util.tree_map(np.asarray, c["ctx"])
    use = bool(c["use_bounds"])
    if bool(c["lane_change"]):
        which = "path to the neighbour lane"
    else:
        which = "bounds path" if use else "route path (bounds path failed or blocked)"
    fig, axes = plt.subplots(1, 3, figsize=(18, 5.2), gridspec_kw={"width_ratios": [1.5, 1.2, 1.0]})
    ax = axes[0]
    draw_scene(ax, scene)
    boxes, valid = np.asarray(ctx.obstacles.boxes), np.asarray(ctx.obstacles.valid)
    blk = np.zeros(boxes.shape[0], bool) if pp is None else np.asarray(pp.blocking)
    for k in range(boxes.shape[0]):
        if valid[k, 0]:
            red = bool(blk[k])
            draw_box(
                ax,
                boxes[k, 0],
                fc=(0.8, 0.1, 0.1, 0.5) if red else (0.12, 0.47, 0.71, 0.3),
                ec="darkred" if red else "tab:blue",
                lw=0.8,
                zorder=3,
            )
    if pp is not None:
        for side, name in ((pp.lower, "lower bound"), (pp.upper, "upper bound")):
            m = np.isfinite(side) & pp.valid & (np.abs(side) < 50)
            xy = np.asarray(to_cartesian(scene.route, pp.route_s[m], side[m]))
            ax.plot(xy[:, 0], xy[:, 1], "-", color="tab:orange", lw=1.0, label=f"path {name}", zorder=4)
    ax.plot(
        path.xy[:, 0],
        path.xy[:, 1],
        "-",
        color="k",
        lw=1.0,
        label=which,
        zorder=4,
    )
    sc = ax.scatter(traj.x, traj.y, c=traj.v, cmap="viridis", s=8, zorder=5)
    fig.colorbar(sc, ax=ax, label="planned speed (m/s)")
    draw_box(
        ax,
        [float(ego.x), float(ego.y), planner.vehicle.length, planner.vehicle.width, float(ego.heading)],
        fc="none",
        ec="k",
        lw=1.2,
        zorder=6,
    )
    pts = np.concatenate([np.stack([traj.x, traj.y], -1), [[float(ego.x), float(ego.y)]]])
    lo, hi = pts.min(0) - 15.0, pts.max(0) + 15.0
    half = 0.5 * max(hi - lo)
    mid = 0.5 * (lo + hi)
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title(
        f"{title} t = {step * float(scene.dt):.1f} s: " + which,
        fontsize=9,
    )
    ax = axes[1]
    ds = path.route_s - float(ctx.s)
    if pp is not None:
        rs = pp.route_s - float(ctx.s)
        ax.fill_between(
            rs,
            np.where(pp.valid, np.clip(pp.lower, -20, 20), np.nan),
            np.where(pp.valid, np.clip(pp.upper, -20, 20), np.nan),
            color="tab:orange",
            alpha=0.2,
            label="path bounds (car reference point)",
        )
        if np.isfinite(pp.blocked_s):
            ax.axvline(float(np.interp(pp.blocked_s, pp.s, rs)), color="0.3", ls="--", label="blockage")
    ax.plot(ds, path.l, "k-", lw=1.2, label="path")
    ax.plot(
        np.interp(traj.s + float(c["s0"]), np.asarray(c["ref"].s), ds),
        np.interp(traj.s + float(c["s0"]), np.asarray(c["ref"].s), path.l),
        "o",
        ms=2,
        color="tab:green",
        label="trajectory points",
    )
    ax.set_xlim(-5.0, max(40.0, float(traj.s[-1]) + 10.0))
    ax.set_xlabel("s along the route from the car (m)")
    ax.set_ylabel("l, offset left of the route (m)")
    ax.legend(fontsize=7)
    keep, change = (float(x) for x in np.asarray(c["lane_costs"]))
    decision = "change to the neighbour lane" if bool(c["lane_change"]) else "keep the lane"
    costs = f" (cost keep {keep:.0f}, change {change:.0f})" if np.isfinite(change) else ""
    ax.set_title(f"SL: bounds and path; decision: {decision}{costs}", fontsize=9)
    ax = axes[2]
    draw_st(ax, planner, c["plan"], c["profile"])
    cl = jax.tree_util.tree_map(np.asarray, c["plan"].scene.classified)
    ax.set_title(
        f"ST graph: {int(cl.is_blocking.sum())} blocking, {int(cl.no_bypass.sum())} not to pass,\n"
        f"{int(cl.blind_zone.sum())} blind zones, {int(cl.rear.hit.any(-1).sum())} closing in from behind",
        fontsize=9,
    )
    fig.tight_layout()
    return fig
