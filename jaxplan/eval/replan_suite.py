"""Suite ``replan``: lazy re-planning against periodic and immediate re-planning in closed loop.

Seeded parking approaches (forward, gear shift, reverse into a slot whose observed
position is biased and noisy) and short forward drives, with phantom obstacles, real
obstacles and crossing pedestrians. Every strategy drives the same scenarios with the
same safety layer, the same drivable planner and the same perception
(:mod:`jaxplan.replan.supervisor`; one compiled simulator, the strategy a traced int).

Figures per strategy over all runs of all seeds, with 95 % confidence intervals (Wilson
for shares, bootstrap over runs for means): ``<strategy>.collision_share``,
``<strategy>.success_share``, ``<strategy>.replans_per_run`` and ``..._ci95_lo`` /
``..._ci95_hi``; paired differences to lazy on the same scenarios; per seed and per kind;
compute per run.
"""

from __future__ import annotations

import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.eval.registry import SuiteArgs, register
from jaxplan.replan import (
    GOAL,
    IMMEDIATE,
    LAZY,
    LOST,
    OBSTACLE,
    PERIOD,
    PERIODIC,
    REASON_NAMES,
    STRATEGY_NAMES,
    ManeuverSimConfig,
    run_summary,
    sample_scenarios,
    simulate,
)

Z95 = 1.959963984540054


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a share ``k / n``."""
    if n == 0:
        return float("nan"), float("nan")
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return float(max(0.0, centre - half)), float(min(1.0, centre + half))


def bootstrap_ci(x, rng: np.random.Generator, stat=np.mean, n_boot: int = 2000) -> tuple[float, float]:
    """Percentile bootstrap 95 % interval of ``stat`` over the rows of ``x`` (resampled together)."""
    x = np.asarray(x)
    if len(x) == 0:
        return float("nan"), float("nan")
    idx = rng.integers(0, len(x), (n_boot, len(x)))
    vals = np.array([stat(x[i]) for i in idx])
    return float(np.percentile(vals, 2.5)), float(np.percentile(vals, 97.5))


def scenarios(seed: int, n: int, **kw):
    """``n`` parking approaches and ``n`` short drives of one seed; kinds ``(2n,)``."""
    park = sample_scenarios(2 * seed, n, "park", **kw)
    drive = sample_scenarios(2 * seed + 1, n, "drive", **kw)
    sc = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), park, drive)
    return sc, np.array(["park"] * n + ["drive"] * n)


def run_strategies(
    n: int, seeds, cfg: ManeuverSimConfig = ManeuverSimConfig(), keep_logs_of: int | None = None, **scenario_kw
):
    """Every seed's ``2 n`` scenarios driven by the three strategies.

    Returns (per-run table: {strategy: {field: (R,) array}} with ``seed``, ``kind``,
    ``pedestrian`` columns; wall times {strategy: [s per seed]}; the scenarios and logs of
    seed ``keep_logs_of`` {strategy: logs}).
    """
    table: dict[int, dict[str, np.ndarray]] = {s: {} for s in (LAZY, PERIODIC, IMMEDIATE)}
    times: dict[int, list[float]] = {s: [] for s in table}
    kept = None
    for seed in seeds:
        sc, kinds = scenarios(seed, n, **scenario_kw)
        ped = np.asarray(sc.dyn_valid).any(-1)
        logs_of_seed = {}
        for s in table:
            t0 = time.perf_counter()
            final, logs = jax.block_until_ready(simulate(sc, s, cfg))
            times[s].append(time.perf_counter() - t0)
            m = run_summary(final)
            m.update(seed=np.full(len(kinds), seed), kind=kinds, pedestrian=ped)
            for k, v in m.items():
                table[s][k] = np.concatenate([table[s][k], v]) if k in table[s] else v
            if seed == keep_logs_of:
                logs_of_seed[s] = jax.tree.map(np.asarray, logs)
        if seed == keep_logs_of:
            kept = (sc, kinds, logs_of_seed, {s: {k: table[s][k][-len(kinds) :] for k in table[s]} for s in table})
    return table, times, kept


def figures(table: dict, times: dict, n_runs_per_call: int, rng: np.random.Generator) -> dict:
    """The suite's metrics from the per-run table."""
    res: dict[str, float] = {}
    for s, m in table.items():
        name = STRATEGY_NAMES[s]
        n = len(m["collided"])
        res[f"{name}.runs"] = n
        for key, col in (("collision_share", m["collided"]), ("success_share", m["success"])):
            k = int(np.sum(col))
            lo, hi = wilson(k, n)
            res[f"{name}.{key}"] = round(k / n, 4)
            res[f"{name}.{key}_ci95_lo"] = round(lo, 4)
            res[f"{name}.{key}_ci95_hi"] = round(hi, 4)
        r = m["replans"].astype(float)
        lo, hi = bootstrap_ci(r, rng)
        res[f"{name}.replans_per_run"] = round(float(r.mean()), 3)
        res[f"{name}.replans_per_run_ci95_lo"] = round(lo, 3)
        res[f"{name}.replans_per_run_ci95_hi"] = round(hi, 3)
        res[f"{name}.replans_while_moving_per_run"] = round(float(m["replans_moving"].mean()), 3)
        res[f"{name}.unnecessary_per_run"] = round(float(m["unnecessary"].mean()), 3)
        res[f"{name}.rejected_plans_per_run"] = round(float(m["rejected"].sum(-1).mean()), 3)
        for j, why in enumerate(("collision", "gear", "stale")):
            res[f"{name}.rejected_{why}_per_run"] = round(float(m["rejected"][:, j].mean()), 4)
        for reason in (GOAL, OBSTACLE, LOST, PERIOD):
            res[f"{name}.replans_{REASON_NAMES[reason]}_per_run"] = round(float(m["reasons"][:, reason].mean()), 3)
        ok = m["success"]
        res[f"{name}.time_to_goal_s"] = round(float(np.nanmean(m["time_to_goal"][ok])), 3) if ok.any() else float("nan")
        res[f"{name}.end_jumps_per_run"] = round(float(m["end_jumps"].mean()), 3)
        for kind in ("park", "drive"):
            sel = m["kind"] == kind
            res[f"{name}.{kind}.collision_share"] = round(float(m["collided"][sel].mean()), 4)
            res[f"{name}.{kind}.success_share"] = round(float(m["success"][sel].mean()), 4)
            res[f"{name}.{kind}.replans_per_run"] = round(float(m["replans"][sel].mean()), 3)
        for tag, sel in (("with_pedestrian", m["pedestrian"]), ("without_pedestrian", ~m["pedestrian"])):
            res[f"{name}.{tag}.collision_share"] = round(float(m["collided"][sel].mean()), 4) if sel.any() else 0.0
        for seed in np.unique(m["seed"]):
            sel = m["seed"] == seed
            res[f"{name}.seed{int(seed)}.collision_share"] = round(float(m["collided"][sel].mean()), 4)
            res[f"{name}.seed{int(seed)}.success_share"] = round(float(m["success"][sel].mean()), 4)
            res[f"{name}.seed{int(seed)}.replans_per_run"] = round(float(m["replans"][sel].mean()), 3)
        # Compute per run: wall time of the batched calls after the first (which compiles).
        t = times[s][1:] if len(times[s]) > 1 else times[s]
        res[f"{name}.ms_per_run"] = round(1e3 * float(np.mean(t)) / n_runs_per_call, 2)
    # The claim that lazy re-planning needs far fewer re-plans at no more collisions, measured on
    # the same scenarios (paired).
    lz = table[LAZY]
    for s in (PERIODIC, IMMEDIATE):
        name = STRATEGY_NAMES[s]
        b = table[s]
        pair = np.stack([lz["replans"], b["replans"]], -1).astype(float)
        ratio = lambda x: x[:, 1].mean() / max(x[:, 0].mean(), 1e-9)  # noqa: E731
        lo, hi = bootstrap_ci(pair, rng, ratio)
        res[f"claim.{name}_over_lazy_replans"] = round(float(ratio(pair)), 3)
        res[f"claim.{name}_over_lazy_replans_ci95_lo"] = round(lo, 3)
        res[f"claim.{name}_over_lazy_replans_ci95_hi"] = round(hi, 3)
        d = np.stack([lz["collided"], b["collided"]], -1).astype(float)
        diff = lambda x: x[:, 0].mean() - x[:, 1].mean()  # noqa: E731
        lo, hi = bootstrap_ci(d, rng, diff)
        res[f"claim.lazy_minus_{name}_collision_share"] = round(float(diff(d)), 4)
        res[f"claim.lazy_minus_{name}_collision_share_ci95_lo"] = round(lo, 4)
        res[f"claim.lazy_minus_{name}_collision_share_ci95_hi"] = round(hi, 4)
        d = np.stack([lz["success"], b["success"]], -1).astype(float)
        lo, hi = bootstrap_ci(d, rng, diff)
        res[f"claim.lazy_minus_{name}_success_share"] = round(float(diff(d)), 4)
        res[f"claim.lazy_minus_{name}_success_share_ci95_lo"] = round(lo, 4)
        res[f"claim.lazy_minus_{name}_success_share_ci95_hi"] = round(hi, 4)
    res["claim.lazy_5x_fewer_replans_than_periodic"] = float(res["claim.periodic_over_lazy_replans_ci95_lo"] >= 5)
    res["claim.lazy_fewer_replans_than_immediate"] = float(res["claim.immediate_over_lazy_replans_ci95_lo"] > 1)
    # "No more collisions": the paired difference's interval reaches down to zero or below.
    coll_lo = [res[f"claim.lazy_minus_{STRATEGY_NAMES[s]}_collision_share_ci95_lo"] for s in (PERIODIC, IMMEDIATE)]
    res["claim.lazy_no_more_collisions"] = float(all(x <= 0 for x in coll_lo))
    res["claim.baselines_collide_as_little_as_lazy"] = float(
        all(res[f"claim.lazy_minus_{STRATEGY_NAMES[s]}_collision_share_ci95_hi"] >= 0 for s in (PERIODIC, IMMEDIATE))
    )
    return res


@register("replan")
def replan_suite(args: SuiteArgs) -> dict:
    n = args.n or (8 if args.quick else 128)  # runs per kind and seed
    n_seeds = 1 if args.quick else 4
    seeds = [args.seed + i for i in range(n_seeds)]
    cfg = ManeuverSimConfig()
    table, times, kept = run_strategies(n, seeds, cfg, keep_logs_of=seeds[0])
    res = figures(table, times, 2 * n, np.random.default_rng(args.seed))
    res["seeds"] = n_seeds
    res["first_call_s_incl_compile"] = round(times[LAZY][0], 2)
    sc, kinds, logs, summary = kept
    plot_timeline(sc, kinds, logs, summary, args.out)
    plot_summary(res, args.out)
    return res


@register("replan_parkout")
def replan_parkout_suite(args: SuiteArgs) -> dict:
    """The park-out planner driven by the same supervisor (host loop, slow)."""
    return parkout_figures(n=args.n or (2 if args.quick else 8), seed=args.seed)


def parkout_figures(n: int, seed: int) -> dict:
    """Park-out runs (``jaxplan.parking.plan_parkout`` through ``ParkoutPlanner``), host loop."""
    from jaxplan.parking import is_out, stop_line
    from jaxplan.replan import SupervisorConfig, simulate_host
    from jaxplan.replan.parkout_adapter import ParkoutPlanner, parkout_scenarios

    pp = ParkoutPlanner()
    sc, _ = parkout_scenarios(seed, n, pp)
    cfg = ManeuverSimConfig(
        planner=pp,
        supervisor=SupervisorConfig(limits=pp.limits, clearance=pp.clearance),
        sensor_range=30.0,
        lat_sigma=0.0,
        steps=300,
    )
    d = stop_line(pp.vehicle, pp.config.c)
    res: dict[str, float] = {"parkout.runs_per_strategy": n}
    for s in (LAZY, PERIODIC, IMMEDIATE):
        rows = []
        for i in range(n):
            fin, _ = simulate_host(jax.tree.map(lambda a: a[i], sc), s, cfg)
            rows.append(
                (
                    int(fin.sup.n_replan),
                    bool(fin.collided),
                    bool(fin.done) and bool(is_out(fin.pose, d, pp.config)),
                    float(fin.t_done),
                    int(fin.sup.n_replan_moving),
                )
            )
        r, c, o, t, mv = (np.array(x) for x in zip(*rows))
        name = STRATEGY_NAMES[s]
        res.update(
            {
                f"parkout.{name}.replans_per_run": float(r.mean()),
                f"parkout.{name}.collision_share": float(c.mean()),
                f"parkout.{name}.out_share": float(o.mean()),
                f"parkout.{name}.time_to_out_s": float(t[o].mean()) if o.any() else float("nan"),
                f"parkout.{name}.replans_while_moving_per_run": float(mv.mean()),
            }
        )
    return res


def pick_run(summary, kinds) -> int:
    """A parking run where lazy re-planned for both goal and obstacle and a pedestrian or
    obstacle made the baselines act, else the lazy run with the most re-plans."""
    m = summary[LAZY]
    park = kinds == "park"
    both = park & (m["reasons"][:, GOAL] > 0) & (m["reasons"][:, OBSTACLE] > 0)
    if both.any():
        return int(np.argmax(both))
    return int(np.argmax(np.where(park, m["replans"], -1)))


_COLOURS = {GOAL: "tab:green", OBSTACLE: "tab:red", PERIOD: "tab:purple", LOST: "k"}


def plot_timeline(sc, kinds, logs, summary, path, run: int | None = None):
    """What the supervisor did in one run, for each strategy: signed speed and gear, the
    distance to the brake-stop point, the collision-queue size, re-plan requests (by reason)
    and arrived plans (installed / rejected); and the paths driven."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from jaxplan.geometry.boxes import box_corners

    i = pick_run(summary, kinds) if run is None else run
    fig = plt.figure(figsize=(15, 10))
    gs = fig.add_gridspec(3, 2, width_ratios=[2.2, 1])
    for row, s in enumerate((LAZY, PERIODIC, IMMEDIATE)):
        ax = fig.add_subplot(gs[row, 0])
        L, m = logs[s], summary[s]
        end = int(np.argmax(L.done[i])) + 1 if L.done[i].any() else L.t.shape[1]
        t = L.t[i, :end]
        ax.plot(t, L.v[i, :end], "C0", label="signed speed [m/s]")
        ax.step(t, L.gear[i, :end], "C7", where="post", lw=1, label="gear (+1 fwd, -1 rev)")
        ax.plot(t, np.clip(L.brake_dist[i, :end], -1, 6), "C1", label="to brake-stop point [m] (clipped at 6)")
        ax.set_ylabel("m/s, m, gear")
        ax.set_ylim(-2.2, 6.5)
        ax2 = ax.twinx()
        ax2.step(t, L.queue_size[i, :end], "tab:olive", where="post", alpha=0.7)
        ax2.set_ylabel("collision-queue size [entries]", color="tab:olive")
        for j in np.nonzero(L.replan[i, :end])[0]:
            ax.axvline(t[j], color=_COLOURS.get(int(L.reason[i, j]), "k"), lw=1, ls="-" if L.necessary[i, j] else ":")
        inst = np.nonzero(L.installed[i, :end])[0]
        rej = np.nonzero(L.rejected[i, :end])[0]
        ax.plot(t[inst], np.full(len(inst), 6.0), "v", color="C0", ms=5)
        ax.plot(t[rej], np.full(len(rej), 6.0), "x", color="C3", ms=7)
        ax.set_title(
            f"{STRATEGY_NAMES[s]}: {int(m['replans'][i])} re-plans ({int(m['unnecessary'][i])} unnecessary, "
            f"{int(m['rejected'][i].sum())} plans rejected), success={bool(m['success'][i])}, "
            f"collided={bool(m['collided'][i])}",
            fontsize=9,
        )
        if row == 0:
            extra = [
                Line2D([], [], color="tab:olive", label="collision-queue size (right axis)"),
                Line2D([], [], color="tab:green", label="re-plan: goal moved"),
                Line2D([], [], color="tab:red", label="re-plan: obstacle"),
                Line2D([], [], color="tab:purple", label="re-plan: periodic"),
                Line2D([], [], color="k", ls=":", label="dotted: not needed"),
                Line2D([], [], color="C0", marker="v", ls="", label="plan installed"),
                Line2D([], [], color="C3", marker="x", ls="", label="plan rejected (old kept)"),
            ]
            h, _ = ax.get_legend_handles_labels()
            ax.legend(handles=h + extra, loc="upper right", fontsize=7, ncol=2)
        if row == 2:
            ax.set_xlabel("time [s]")
    ax = fig.add_subplot(gs[:, 1])
    for s, c in zip((LAZY, PERIODIC, IMMEDIATE), ("C0", "C1", "C2")):
        L = logs[s]
        end = int(np.argmax(L.done[i])) + 1 if L.done[i].any() else L.t.shape[1]
        ax.plot(L.x[i, :end], L.y[i, :end], c, lw=1.5, label=STRATEGY_NAMES[s])
    one = jax.tree.map(lambda a: np.asarray(a[i]), sc)
    for b, v in zip(one.real, one.real_valid):
        if v:
            cc = np.asarray(box_corners(jnp.asarray(b)))
            ax.fill(cc[:, 0], cc[:, 1], color="k", alpha=0.6)
    for b, v in zip(one.phantom, one.phantom_valid):
        if v:
            cc = np.asarray(box_corners(jnp.asarray(b)))
            ax.fill(cc[:, 0], cc[:, 1], color="0.6", alpha=0.5)
    for p, d, v in zip(one.dyn_point, one.dyn_dir, one.dyn_valid):
        if v:
            ax.plot([p[0] - 4 * d[0], p[0] + 4 * d[0]], [p[1] - 4 * d[1], p[1] + 4 * d[1]], "m--", lw=1)
    ax.plot(one.goal[0], one.goal[1], "r*", ms=12, label="true goal")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("paths (black: obstacle, grey: phantom,\nmagenta: pedestrian crossing)", fontsize=9)
    ax.legend(fontsize=8)
    fig.suptitle(f"closed-loop supervisor timeline, {kinds[i]} run {i}")
    fig.tight_layout()
    fig.savefig(os.path.join(path, "replan_timeline.png"), dpi=90)
    plt.close(fig)


def plot_summary(res, path):
    """Collision share, success share and re-plans per run per strategy with 95 % intervals."""
    import matplotlib.pyplot as plt

    keys = (
        ("collision_share", "collision share [runs]"),
        ("success_share", "success share [runs]"),
        ("replans_per_run", "re-plans per run [count]"),
    )
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for ax, (k, label) in zip(axes, keys):
        vals = np.array([res[f"{n}.{k}"] for n in STRATEGY_NAMES])
        lo = np.array([res[f"{n}.{k}_ci95_lo"] for n in STRATEGY_NAMES])
        hi = np.array([res[f"{n}.{k}_ci95_hi"] for n in STRATEGY_NAMES])
        ax.bar(STRATEGY_NAMES, vals, yerr=[vals - lo, hi - vals], capsize=4, color=["C0", "C1", "C2"])
        ax.set_ylabel(label)
        ax.set_title(f"{k} (95 % CI, {res['lazy.runs']} runs each)", fontsize=9)
    fig.tight_layout()
    fig.savefig(os.path.join(path, "replan_summary.png"), dpi=90)
    plt.close(fig)
