"""Suite ``replan``: lazy re-planning against periodic and immediate re-planning in closed loop.

Seeded parking approaches (forward, gear shift, reverse into a slot whose observed
position is biased and noisy) and short forward drives, with phantom obstacles,
real obstacles and crossing pedestrians. Every strategy drives the same scenarios
(one compiled simulator: ``lax.scan`` over time of ``vmap``-ed steps).
"""
from __future__ import annotations

import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.eval.registry import SuiteArgs, register
from jaxplan.replan import (GOAL, IMMEDIATE, LAZY, OBSTACLE, PERIOD, PERIODIC, REASON_NAMES, STRATEGY_NAMES,
                            SimConfig, run_summary, sample_scenarios, simulate)


def _figures(m: dict, sel) -> dict:
    ok = m["success"][sel]
    ttg = m["time_to_goal"][sel][ok]
    return {"replans_per_run": float(m["replans"][sel].mean()),
            "unnecessary_per_run": float(m["unnecessary"][sel].mean()),
            "collision_rate": float(m["collided"][sel].mean()),
            "success_rate": float(ok.mean()),
            "time_to_goal_s": float(ttg.mean()) if ttg.size else float("nan"),
            "end_jumps_per_run": float(m["end_jumps"][sel].mean()),
            "replans_while_moving_per_run": float(m["replans_moving"][sel].mean())}


def run_strategies(n: int, seed: int, cfg: SimConfig = SimConfig(), **scenario_kw):
    """``n`` parking approaches and ``n`` short drives, each driven by the three strategies.

    ``scenario_kw`` go to ``sample_scenarios`` (obstacle probabilities, bias, noise).

    Returns (scenarios, kinds ``(2n,)`` str, {strategy: (summary dict, logs)}).
    """
    park = sample_scenarios(seed, n, "park", **scenario_kw)
    drive = sample_scenarios(seed + 1, n, "drive", **scenario_kw)
    sc = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), park, drive)
    kinds = np.array(["park"] * n + ["drive"] * n)
    out = {}
    times = {}
    for s in (LAZY, PERIODIC, IMMEDIATE):
        t0 = time.perf_counter()
        final, logs = jax.block_until_ready(simulate(sc, s, cfg))
        times[s] = time.perf_counter() - t0  # the first call includes the compilation
        out[s] = (run_summary(final), jax.tree.map(np.asarray, logs))
    run_strategies.last_times = times
    return sc, kinds, out


@register("replan")
def replan_suite(args: SuiteArgs) -> dict:
    n = args.n or (16 if args.quick else 128)
    sc, kinds, out = run_strategies(n, args.seed)
    res: dict[str, float] = {"runs_per_strategy": 2 * n}
    tm = run_strategies.last_times
    cfg = SimConfig()
    res["first_call_s_incl_compile"] = round(tm[LAZY], 2)
    for s in (PERIODIC, IMMEDIATE):
        res[f"{STRATEGY_NAMES[s]}.sim_steps_per_s"] = round(2 * n * cfg.steps / tm[s])
    for s, (m, _) in out.items():
        name = STRATEGY_NAMES[s]
        for group, sel in (("all", slice(None)), ("park", kinds == "park"), ("drive", kinds == "drive")):
            for k, v in _figures(m, sel).items():
                res[f"{name}.{group}.{k}"] = round(v, 4)
        for r in (GOAL, OBSTACLE, PERIOD):
            res[f"{name}.all.replans_{REASON_NAMES[r]}_per_run"] = round(float(m["reasons"][:, r].mean()), 4)
    lz, pe, im = (out[s][0] for s in (LAZY, PERIODIC, IMMEDIATE))
    for group, sel in (("all", slice(None)), ("park", kinds == "park"), ("drive", kinds == "drive")):
        rl = lz["replans"][sel].mean()
        rp, ri = pe["replans"][sel].mean(), im["replans"][sel].mean()
        res[f"claim.{group}.periodic_over_lazy_replans"] = round(float(rp / max(rl, 1e-9)), 3)
        res[f"claim.{group}.immediate_over_lazy_replans"] = round(float(ri / max(rl, 1e-9)), 3)
    col = {s: out[s][0]["collided"].mean() for s in out}
    suc = {s: out[s][0]["success"].mean() for s in out}
    res["claim.lazy_5x_fewer_than_periodic"] = float(res["claim.all.periodic_over_lazy_replans"] >= 5)
    res["claim.lazy_fewer_than_immediate"] = float(res["claim.all.immediate_over_lazy_replans"] > 1)
    res["claim.lazy_no_more_collisions"] = float(col[LAZY] <= min(col[PERIODIC], col[IMMEDIATE]))
    res["claim.lazy_no_lower_success"] = float(suc[LAZY] >= max(suc[PERIODIC], suc[IMMEDIATE]))
    res["claim.holds"] = float(all(res[k] for k in ("claim.lazy_5x_fewer_than_periodic", "claim.lazy_fewer_than_immediate",
                                                    "claim.lazy_no_more_collisions", "claim.lazy_no_lower_success")))
    _plot_timeline(out, kinds, args.out)
    _plot_summary(res, args.out)
    if not args.quick:  # the park-out planner (issue 6) driven by the same supervisor
        res.update(parkout_figures(n=max(4, n // 16), seed=args.seed))
    return res


def parkout_figures(n: int, seed: int) -> dict:
    """Park-out runs (``jaxplan.parking.plan_parkout`` through ``ParkoutPlanner``), host loop."""
    from jaxplan.parking import is_out, stop_line
    from jaxplan.replan import simulate_host
    from jaxplan.replan.parkout_adapter import ParkoutPlanner, parkout_scenarios

    pp = ParkoutPlanner()
    sc, _ = parkout_scenarios(seed, n, pp)
    cfg = SimConfig(planner=pp, sensor_range=30.0, lat_sigma=0.0, steps=300)
    d = stop_line(pp.vehicle, pp.config.c)
    res: dict[str, float] = {"parkout.runs_per_strategy": n}
    for s in (LAZY, PERIODIC, IMMEDIATE):
        rows = []
        for i in range(n):
            fin, _ = simulate_host(jax.tree.map(lambda a: a[i], sc), s, cfg)
            rows.append((int(fin.n_replan), bool(fin.collided), bool(fin.done) and bool(is_out(fin.pose, d, pp.config)),
                         float(fin.t_done), int(fin.n_replan_moving)))
        r, c, o, t, mv = (np.array(x) for x in zip(*rows))
        name = STRATEGY_NAMES[s]
        res.update({f"parkout.{name}.replans_per_run": float(r.mean()), f"parkout.{name}.collision_rate": float(c.mean()),
                    f"parkout.{name}.out_rate": float(o.mean()),
                    f"parkout.{name}.time_to_out_s": float(t[o].mean()) if o.any() else float("nan"),
                    f"parkout.{name}.replans_while_moving_per_run": float(mv.mean())})
    return res


def _pick_run(out, kinds) -> int:
    """A parking run where the lazy supervisor re-planned for both goal and obstacle, else the busiest one."""
    m, _ = out[LAZY]
    park = kinds == "park"
    both = park & (m["reasons"][:, GOAL] > 0) & (m["reasons"][:, OBSTACLE] > 0)
    if both.any():
        return int(np.argmax(both))
    return int(np.argmax(np.where(park, m["replans"], -1)))


def _plot_timeline(out, kinds, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    i = _pick_run(out, kinds)
    colours = {GOAL: "tab:green", OBSTACLE: "tab:red", PERIOD: "tab:purple", 3: "k"}
    fig, axes = plt.subplots(3, 1, figsize=(10, 8.5), sharex=True)
    for ax, s in zip(axes, (LAZY, PERIODIC, IMMEDIATE)):
        m, L = out[s]
        t = L.t[i]
        end = int(np.argmax(L.done[i])) + 1 if L.done[i].any() else len(t)
        t = t[:end]
        ax.plot(t, L.v[i, :end], "C0", label="speed [m/s]")
        ax.plot(t, np.clip(L.brake_dist[i, :end], -1, 8), "C1", label="to brake-stop point [m] (clipped)")
        ax2 = ax.twinx()
        ax2.step(t, L.queue_size[i, :end], "C2", where="post", alpha=0.6, label="queue size")
        ax2.set_ylabel("queue size")
        for j in np.nonzero(L.replan[i, :end])[0]:
            ax.axvline(t[j], color=colours.get(int(L.reason[i, j]), "k"), lw=1, ls="-" if L.necessary[i, j] else ":")
        ax.set_title(f"{STRATEGY_NAMES[s]}: {int(m['replans'][i])} re-plans ({int(m['unnecessary'][i])} unnecessary), "
                     f"success={bool(m['success'][i])}, collided={bool(m['collided'][i])}", fontsize=10)
        ax.set_ylabel("m/s, m")
        if s == LAZY:
            h1, l1 = ax.get_legend_handles_labels()
            h2, l2 = ax2.get_legend_handles_labels()
            ax.legend(h1 + h2, l1 + l2, loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]   (re-plans: green goal, red obstacle, purple periodic; dotted = unnecessary)")
    fig.suptitle(f"closed-loop timeline of parking run {i}")
    fig.tight_layout()
    fig.savefig(os.path.join(path, "replan_timeline.png"), dpi=90)
    plt.close(fig)


def _plot_summary(res, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = ("replans_per_run", "unnecessary_per_run", "collision_rate", "success_rate", "end_jumps_per_run")
    fig, axes = plt.subplots(1, len(keys), figsize=(15, 3.2))
    for ax, k in zip(axes, keys):
        vals = [res[f"{n}.all.{k}"] for n in STRATEGY_NAMES]
        ax.bar(STRATEGY_NAMES, vals, color=["C0", "C1", "C2"])
        ax.set_title(k, fontsize=10)
    fig.tight_layout()
    fig.savefig(os.path.join(path, "replan_summary.png"), dpi=90)
    plt.close(fig)
