"""Benchmark: ST-graph speed plans per second (7 s horizon, 20 obstacles) at batch 1 / 100 / 1,000.

Every plan projects the 20 moving obstacles (boxes every 0.1 s, resampled to the DP's
check times) to the path once per time, classifies them (blocking, non-blocking with
decisions, behind), builds the cost tables, and runs the exact DP over the reachable band
with backtracking: ``plan_speed``. ``plans_per_s`` (top level, batch size -> plans/s) is
that figure on the default speed grid; ``plans_per_s_with_qp`` adds the smoothing QP and
the composed trajectory (what the ``pathspeed`` planner runs every cycle). Compile time
is reported separately; other grids are timed at batch 100. ``qp`` compares the QP
solver (this project's constant-matrix ADMM) with qpax's interior point method and
jaxopt's ``BoxOSQP`` on the same QPs: solve time per QP, the share of the cases OSQP (run to
1e-7) solves that each solver solves, and the largest and 95th-percentile difference of the
solution (accelerations, m/s^2) from OSQP's there.

Figures from a loaded machine are rough; ``--devices N`` splits each batch over N XLA
host devices (one per core) with ``jaxplan.eval.batch.sharded_map``.

    python experiments/bench_speed.py [--batches 1 100 1000] [--devices 2] [--out results/bench_speed.json]
"""
from __future__ import annotations

import argparse
import os
import platform
import sys


def _parse(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 100, 1000])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--devices", type=int, default=1, help="XLA host devices to split each batch over (CPU)")
    ap.add_argument("--qp-cases", type=int, default=64, help="QPs in the solver comparison (0: skip it)")
    ap.add_argument("--out", default="results/bench_speed.json")
    return ap.parse_args(argv)


K = 20


def scenes(rng, B, horizon):
    """B random straight-road scenes with K obstacles in three lanes (some crossing)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxplan.geometry.frenet import reference_line
    from jaxplan.types import Obstacles

    t = np.arange(int(round(horizon / 0.1)) + 1) * 0.1
    x0 = rng.uniform(5, 120, (B, K))
    lane = rng.integers(-1, 2, (B, K)) * 3.5
    vx = rng.uniform(0, 15, (B, K))
    boxes = np.zeros((B, K, len(t), 5), np.float32)
    boxes[..., 0] = x0[..., None] + vx[..., None] * t
    boxes[..., 1] = lane[..., None]
    boxes[..., 2], boxes[..., 3] = 4.5, 1.8
    cross = rng.uniform(size=(B, K)) < 0.1  # pedestrians crossing
    boxes[..., 1] = np.where(cross[..., None], -7 + 1.3 * t, boxes[..., 1])
    boxes[..., 0] = np.where(cross[..., None], x0[..., None], boxes[..., 0])
    boxes[..., 2] = np.where(cross[..., None], 0.6, 4.5)
    boxes[..., 3] = np.where(cross[..., None], 0.6, 1.8)
    obs = Obstacles(jnp.asarray(boxes), jnp.ones((B, K, len(t)), bool), jnp.asarray(np.tile(t, (B, 1)), jnp.float32))
    ref = np.stack([np.linspace(-20, 400, 8), np.zeros(8)], -1)
    refs = jax.vmap(reference_line)(jnp.asarray(np.tile(ref, (B, 1, 1)), jnp.float32))
    return refs, obs, jnp.asarray(rng.uniform(5, 15, B), jnp.float32)


def main(argv=None):
    args = _parse(argv if argv is not None else sys.argv[1:])
    if args.devices > 1:
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                                   f" --xla_force_host_platform_device_count={args.devices}")
    import jax
    import numpy as np

    from jaxplan.eval.batch import sharded_map
    from jaxplan.eval.timing import best_time, timed, write_figures
    from jaxplan.speed import CostWeights, SpeedConfig
    from jaxplan.speed.compose import compose_profile
    from jaxplan.speed.dp import dp_band, map_batched, plan_one
    from jaxplan.speed.smooth import SmoothWeights, smooth_plan
    from jaxplan.types import VehicleParams

    rng = np.random.default_rng(0)
    veh = VehicleParams()

    def planner_fn(cfg, with_qp):
        w = CostWeights.default()

        def one(ref, obs, v0):
            plan = plan_one(ref, obs, v0, 0.0, 20.0, None, None, veh, cfg, w)
            if not with_qp:
                return plan.s, plan.v, plan.cost
            prof = smooth_plan(plan, v0, 0.0, cfg, SmoothWeights())
            tr = compose_profile(ref, 20.0, prof)
            return tr.x, tr.y, tr.v, prof.ok

        return jax.jit(lambda *batch: map_batched(one, 1, batch))  # plan_speed's batching (chunks of BATCH_CHUNK)

    def bench(fn, B, reps):
        refs, obs, v0 = scenes(rng, B, 7.0)
        batch = (refs, obs, v0)
        run = lambda: jax.block_until_ready(sharded_map(lambda b: fn(*b), batch))
        _, compile_s = timed(run)
        best = best_time(run, reps)
        return B / best, compile_s

    grids = {
        "default (dt 1 s, ds 1 m)": SpeedConfig(),
        "fine (dt 1 s, ds 0.5 m)": SpeedConfig(ds=0.5),
        "coarse (dt 1 s, ds 2 m)": SpeedConfig(ds=2.0, a_min=-4.0),
    }
    fig = {"obstacles": K, "horizon_s": 7.0, "devices": jax.device_count(), "device": str(jax.devices()[0]),
           "cpu_count": os.cpu_count(), "machine": platform.machine(), "plans_per_s": {}, "plans_per_s_with_qp": {},
           "compile_s": {}, "grids": {}}
    cfg = SpeedConfig()
    for B in args.batches:
        pps, comp = bench(planner_fn(cfg, False), B, args.reps)
        fig["plans_per_s"][str(B)] = round(pps, 1)
        fig["compile_s"][str(B)] = round(comp, 1)
        print(f"default grid, batch {B:5d}: {pps:9.1f} plans/s (DP)  compile {comp:.1f} s", flush=True)
        pps, _ = bench(planner_fn(cfg, True), B, args.reps)
        fig["plans_per_s_with_qp"][str(B)] = round(pps, 1)
        print(f"default grid, batch {B:5d}: {pps:9.1f} plans/s (DP + QP + trajectory)", flush=True)
    for name, g in grids.items():
        n_states = g.n_v * sum(dp_band(g)[0])  # the DP's states: every speed x the band's h
        pps, _ = bench(planner_fn(g, False), 100, args.reps)
        fig["grids"][name] = {"ds": g.ds, "dv": g.dv, "da": g.da, "accels": len(g.accel_offsets),
                              "states": int(n_states), "transitions": int(n_states * len(g.accel_offsets)),
                              "plans_per_s_batch100": round(pps, 1)}
        print(f"{name:26s} states {fig['grids'][name]['states']:6d}: {pps:9.1f} plans/s at batch 100", flush=True)
    if args.qp_cases:
        fig["qp"] = qp_comparison(args.qp_cases, rng, args.reps)
    write_figures(fig, args.out)


def qp_comparison(n_cases, rng, reps):
    """The smoothing QP on ``n_cases`` DP plans: own ADMM vs qpax vs jaxopt BoxOSQP."""
    import jax
    import jax.numpy as jnp
    import numpy as np
    import osqp
    import scipy.sparse as sps

    from jaxplan.eval.timing import best_time
    from jaxplan.solvers import LadderSettings, admm_prefactored
    from jaxplan.speed import CostWeights, SpeedConfig, plan_one, profile_at
    from jaxplan.speed.smooth import SmoothWeights, corridor, qp_matrices, qp_problem
    from jaxplan.types import VehicleParams

    cfg, w, veh = SpeedConfig(), SmoothWeights(), VehicleParams()
    n, h = int(round(cfg.horizon / cfg.qp_dt)), cfg.qp_dt
    refs, obs, v0 = scenes(rng, n_cases, 7.0)

    def problem(ref, ob, v):
        plan = plan_one(ref, ob, v, 0.0, 20.0, None, None, veh, cfg, CostWeights.default())
        t = jnp.arange(1, n + 1, dtype=jnp.float32) * h
        s_ref, v_ref, _ = profile_at(plan, t)
        lo, up = corridor(plan, cfg, t)
        return qp_problem(s_ref, v_ref, lo, up, jnp.full((n,), cfg.v_max), 0.0, v, cfg, w)[:3]  # (no slack)

    q, l, u = (np.asarray(a, np.float64) for a in jax.jit(jax.vmap(problem))(refs, obs, v0))
    m = qp_matrices(n, h, w)
    P, A = sps.csc_matrix(m["P"]), sps.csc_matrix(m["A"])
    ref_x, solved = [], []
    for i in range(n_cases):
        lo = np.where(l[i] < -1e19, -np.inf, l[i])
        hi = np.where(u[i] > 1e19, np.inf, u[i])
        solver = osqp.OSQP()
        solver.setup(P, q[i], A, lo, hi, verbose=False, eps_abs=1e-7, eps_rel=1e-7, max_iter=200000, polish=True)
        res = solver.solve()
        solved.append(res.info.status == "solved")
        ref_x.append(res.x)
    ref_x, solved = np.array(ref_x), np.array(solved)

    def errors(x, ok):
        """Error figures of solutions ``x`` against OSQP where both solved (``ok (cases,)``)."""
        sel = ok & solved & np.all(np.isfinite(x[:, :n]), -1)
        e = np.abs(x[sel, :n] - ref_x[sel, :n]).max(-1)
        return {"solved_share_of_osqp_solved": float(sel.sum() / max(solved.sum(), 1)),
                "max_abs_err": float(e.max()) if e.size else float("nan"),
                "p95_abs_err": float(np.percentile(e, 95)) if e.size else float("nan")}

    out = {"cases": n_cases, "variables": int(m["P"].shape[0]), "constraints": int(m["A"].shape[0]),
           "osqp_solved_share": float(solved.mean()),
           "note": "errors in m/s^2 over the cases the solver and OSQP (1e-7, polished) both solved"}
    qj, lj, uj = (jnp.asarray(a, jnp.float32) for a in (q, l, u))
    sc = LadderSettings()
    own = jax.jit(jax.vmap(lambda a, b, c: admm_prefactored(m["fixed"], a, b, c, sc)))
    x, rp, rd = (np.asarray(a) for a in own(qj, lj, uj))
    t = best_time(lambda: jax.block_until_ready(own(qj, lj, uj)), reps)
    out["admm"] = {"ms_per_qp": 1e3 * t / n_cases, **errors(x, (rp < sc.eps_prim) & (rd < sc.eps_dual))}
    try:
        import qpax

        Pj, Aj = jnp.asarray(m["P"], jnp.float32), jnp.asarray(m["A"], jnp.float32)
        fin_l, fin_u = np.isfinite(np.where(l < -1e19, np.inf, l))[0], np.isfinite(np.where(u > 1e19, np.inf, u))[0]
        G = jnp.concatenate([Aj[fin_u], -Aj[fin_l]])

        def qpax_one(a, b, c):
            g = jnp.concatenate([c[fin_u], -b[fin_l]])
            return qpax.solve_qp(Pj, a, jnp.zeros((0, Pj.shape[0])), jnp.zeros((0,)), G, g, solver_tol=1e-5,
                                 max_iter=40)[0]

        fq = jax.jit(jax.vmap(qpax_one))
        x = np.asarray(fq(qj, lj, uj))
        t = best_time(lambda: jax.block_until_ready(fq(qj, lj, uj)), reps)
        out["qpax"] = {"ms_per_qp": 1e3 * t / n_cases, **errors(x, np.ones(n_cases, bool))}
    except Exception as e:  # the comparison is an extra: say why it is missing
        out["qpax"] = {"error": f"{type(e).__name__}: {e}"}
    try:
        from jaxopt import BoxOSQP

        Pj, Aj = jnp.asarray(m["P"], jnp.float32), jnp.asarray(m["A"], jnp.float32)
        box = BoxOSQP(tol=1e-4, maxiter=4000, jit=True)

        def box_one(a, b, c):
            return box.run(params_obj=(Pj, a), params_eq=Aj, params_ineq=(b, c)).params.primal[0]

        fb = jax.jit(jax.vmap(box_one))
        x = np.asarray(fb(qj, lj, uj))
        t = best_time(lambda: jax.block_until_ready(fb(qj, lj, uj)), reps)
        out["boxosqp"] = {"ms_per_qp": 1e3 * t / n_cases, **errors(x, np.ones(n_cases, bool))}
    except Exception as e:
        out["boxosqp"] = {"error": f"{type(e).__name__}: {e}"}
    for k in ("admm", "qpax", "boxosqp"):
        print(f"QP {k:8s}: {out[k]}", flush=True)
    return out


if __name__ == "__main__":
    main()
