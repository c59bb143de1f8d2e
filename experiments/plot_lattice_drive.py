"""Plot what the ``lattice`` planner did in a closed-loop drive of a built-in scene.

Drives one built-in scene (a survivable one, ``jaxplan.scenarios.builtin``) with the
registered ``lattice`` planner, then re-plans from the driven state at a few steps
(``LatticePlanner.plan_result``: exactly the plan the drive made there, exact tracking)
and draws, per step, the fan of candidates (grey: rejected by the feasibility filter;
red dotted: hits an obstacle or its safety buffer; coloured by cost: the free ones),
the chosen plan, the obstacles over the horizon (darker = later) and the whole driven
path. Axes in metres.

    python experiments/plot_lattice_drive.py [--kind parked_cars] [--steps 0 30 60]
                                             [--out docs/img/lattice_drive.png]
"""
from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kind", default="parked_cars")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, nargs="+", default=[0, 30, 60])
    ap.add_argument("--n-steps", type=int, default=120)
    ap.add_argument("--out", default="docs/img/lattice_drive.png")
    args = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Polygon as MplPolygon

    from jaxplan.geometry import box_corners
    from jaxplan.lattice.cost import MODE_NAMES
    from jaxplan.planner import EgoState, make_planner
    from jaxplan.scenarios.batch import stack_scenes
    from jaxplan.scenarios.builtin import KINDS, _generate
    from jaxplan.sim.rollout import SimConfig, rollout

    if args.kind not in KINDS:
        raise SystemExit(f"plot_lattice_drive: --kind must be one of {', '.join(KINDS)}, got {args.kind!r}")
    (_, rec), = _generate(1, args.seed, kinds=(args.kind,))
    planner = make_planner("lattice")
    cfg = SimConfig(n_steps=args.n_steps, stop_at_goal=False)
    batch = stack_scenes([rec.scene], min_steps=cfg.n_steps + 1)
    log = jax.tree_util.tree_map(lambda a: np.asarray(a)[0], rollout(planner, batch, cfg))
    scene = jax.tree_util.tree_map(lambda a: a[0], batch)
    veh = planner.vehicle
    plan_result = jax.jit(planner.plan_result)
    steps = [k for k in args.steps if k <= int(log.end_step)]
    fig, axes = plt.subplots(1, len(steps), figsize=(6.5 * len(steps), 7), squeeze=False)
    for ax, k in zip(axes[0], steps):
        h = log.heading[k]
        off = veh.center_offset
        ego = EgoState(jnp.asarray(log.x[k] - off * np.cos(h)), jnp.asarray(log.y[k] - off * np.sin(h)),
                       jnp.asarray(h), jnp.asarray(log.v[k]), jnp.asarray(log.a[k]), jnp.asarray(log.kappa[k]))
        res = jax.tree_util.tree_map(np.asarray, plan_result(planner.init_params(), scene, ego, jnp.asarray(k)))
        x, y = res.candidates.traj.x, res.candidates.traj.y
        lines = np.stack([x, y], -1)
        avail, feas = res.candidates.available & res.finite, res.feasible
        hit = res.collided | res.collided_margin
        free = avail & feas & ~hit
        for m, mv in zip(np.asarray(scene.drivable), np.asarray(scene.drivable_valid)):
            if mv.any():
                ax.fill(m[mv, 0], m[mv, 1], color="0.93", zorder=0)
        ax.add_collection(LineCollection(lines[avail & ~feas], colors="0.7", linewidths=0.3))
        ax.add_collection(LineCollection(lines[avail & feas & hit], colors="C3", linewidths=0.4, linestyles=":"))
        c = res.cost[free]
        lc = LineCollection(lines[free], array=np.log10(np.maximum(c - c.min(), 0) + 1e-2), cmap="viridis",
                            linewidths=0.6)
        ax.add_collection(lc)
        plt.colorbar(lc, ax=ax, fraction=0.025, label="log10 (cost - best + 0.01)")
        obs = res.obstacles
        T = obs.boxes.shape[-2]
        for j in range(obs.boxes.shape[0]):
            for q, s in enumerate(range(0, T, 10)):
                if obs.valid[j, s]:
                    ax.add_patch(MplPolygon(np.asarray(box_corners(jnp.asarray(obs.boxes[j, s]))), closed=True,
                                            facecolor="C3", edgecolor="C3",
                                            alpha=0.15 + 0.6 * q / max(1, (T - 1) // 10)))
        v = log.valid
        ax.plot(log.x[v], log.y[v], "b--", lw=1, label="driven path (box centre)")
        i = int(res.chosen)
        ax.plot(x[i], y[i], "k-", lw=2.2, label=f"chosen ({MODE_NAMES[int(res.mode)]}, level "
                                                f"{int(res.candidates.level[i])})")
        ego_box = np.array([log.x[k], log.y[k], veh.length, veh.width, h])
        ax.add_patch(MplPolygon(np.asarray(box_corners(jnp.asarray(ego_box, jnp.float32))), closed=True,
                                facecolor="C0", edgecolor="k"))
        n_av = int(avail.sum())
        ax.set_title(f"{rec.name}, t = {k * cfg.dt:.1f} s, v = {log.v[k]:.1f} m/s\n{n_av} candidates, "
                     f"{int((avail & ~feas).sum())} rejected as infeasible,\n{int((avail & feas & hit).sum())} "
                     f"feasible but hitting an obstacle or its buffer", fontsize=9)
        px, py = np.append(x[avail].ravel(), log.x[k]), np.append(y[avail].ravel(), log.y[k])
        half = 0.5 * max(np.ptp(px), np.ptp(py)) + 8.0  # a square window about the fan
        cx, cy = 0.5 * (px.min() + px.max()), 0.5 * (py.min() + py.max())
        ax.set_xlim(cx - half, cx + half)
        ax.set_ylim(cy - half, cy + half)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.legend(loc="upper left", fontsize=7)
    fig.tight_layout()
    fig.savefig(args.out, dpi=80)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
