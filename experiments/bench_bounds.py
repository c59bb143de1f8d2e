"""Benchmark: path bounds for 20-point frames against 32 obstacles, and the path QP against peers.

1. Frames per second of ``path_bounds`` (contour, exact, SL box, centre line) for batches
   of 1, 100 and 10,000 frames (large batches run in chunks of ``--chunk`` frames through
   one compiled function; compile time separate). The contour figure is the top-level
   ``frames_per_s`` (batch size as a string -> frames/s), with the share of overlapping
   pairs the broad phase gave the construction.
2. The path QP (piecewise jerk, curvature and jerk bounds, ``--qp-points`` stations) on
   random corridors: this project's ADMM (``optimize_path``) and jaxopt's ``BoxOSQP`` on the
   same problems against OSQP (float64, eps 1e-8, polished) as the reference: ms per frame,
   the largest ``|l - l_osqp|``, the share solved (and the share whose answer is the polished
   solution, ``PathQPConfig.polish``). The ADMM runs the frames as one batch;
   ``BoxOSQP`` runs them one by one through one compiled function (under ``vmap`` its loop
   runs every frame until the slowest has converged), and also as one ``vmap`` batch of
   ``--box-vmap-frames`` frames.

The JSON is written after the throughput part and again at the end; the load average
before the run is recorded (timings on a loaded machine are rough).

    python experiments/bench_bounds.py [--batches 1 100 10000] [--out results/bench_bounds.json]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.bounds.frenet_bounds import CASE_UNCONSTRUCTED, path_bounds
from jaxplan.bounds.optimize import optimize_path
from jaxplan.bounds.path_qp import PathQPConfig, PathWeights, curvature_bounds, state_problem
from jaxplan.eval.bounds_suite import CAR, LANE, make_scenarios
from jaxplan.eval.timing import best_time, write_figures
from jaxplan.geometry import reference_line


def random_corridors(rng, n, T, ds):
    """Corridors with one or two obstacle bumps: lower, upper ``(n, T)``, init ``(n, 3)``."""
    lo = np.full((n, T), -1.5)
    up = np.full((n, T), 5.0)
    for f in range(n):
        for _ in range(rng.integers(1, 3)):
            a = rng.integers(int(8 / ds), T - 5)
            b = a + rng.integers(2, 12)
            if rng.uniform() < 0.5:
                lo[f, a:b] = rng.uniform(-1.0, 2.5)
            else:
                up[f, a:b] = rng.uniform(-1.0, 1.0)
    init = np.stack([rng.uniform(-0.3, 0.3, n), rng.uniform(-0.05, 0.05, n), np.zeros(n)], -1)
    return lo, up, init


def qp_bench(n, T, ds, reps, box_tol, box_vmap=0):
    import jaxopt
    import osqp
    import scipy.sparse as sp

    rng = np.random.default_rng(1)
    lo, up, init = random_corridors(rng, n, T, ds)
    cfg = PathQPConfig(jerk_max=0.2)
    k_max = float(np.tan(CAR.max_steer) / CAR.wheelbase)
    dlo, dhi = curvature_bounds(jnp.zeros((T,)), k_max)
    f32 = lambda x: jnp.asarray(x, jnp.float32)
    dl_b = (jnp.full((T,), -cfg.dl_max), jnp.full((T,), cfg.dl_max))
    ours = jax.jit(lambda a, b, c: optimize_path(a, b, ds, None, c, None, cfg, dl_b, (dlo, dhi)))
    args = (f32(lo), f32(up), f32(init))

    def problem(a, b, c):
        return state_problem(jnp.float32(ds), jnp.zeros(T, jnp.float32), a, b, dl_b[0], dl_b[1], dlo, dhi,
                             cfg.jerk_max, c, PathWeights())

    box = jaxopt.BoxOSQP(tol=box_tol, maxiter=4000)

    def box_one(a, b, c):
        P, q, A, l_, u_ = problem(a, b, c)
        sol = box.run(params_obj=(P, q), params_eq=A, params_ineq=(l_, u_)).params
        return sol.primal[0][:T]

    peer_one = jax.jit(box_one)
    peer = lambda: jnp.stack([peer_one(*(a[f] for a in args)) for f in range(n)])
    out = {}
    if box_vmap:
        nb = min(n, box_vmap)
        vm = jax.jit(jax.vmap(box_one))
        sub = tuple(a[:nb] for a in args)
        jax.block_until_ready(vm(*sub))
        out["boxosqp_vmap_frames"] = nb
        out["boxosqp_vmap_ms_per_frame"] = round(1e3 * best_time(lambda: jax.block_until_ready(vm(*sub)), 1) / nb, 4)
    for name, fn in (("admm", lambda: ours(*args)), ("boxosqp", peer)):
        t = time.perf_counter()
        r = jax.block_until_ready(fn())
        out[f"{name}_compile_s"] = round(time.perf_counter() - t, 2)
        dt = best_time(lambda: jax.block_until_ready(fn()), reps)
        out[f"{name}_ms_per_frame"] = round(1e3 * dt / n, 4)
        out[f"_{name}"] = r
    # Reference: OSQP in float64.
    ref_l, solved = [], []
    for f in range(n):
        P, q, A, l_, u_ = (np.asarray(x, np.float64) for x in problem(*(a[f] for a in args)))
        if np.any(l_ > u_):  # the corridor closes somewhere: infeasible by construction (OSQP refuses it)
            solved.append(False)
            ref_l.append(np.full(T, np.nan))
            continue
        m = osqp.OSQP()
        m.setup(sp.csc_matrix(np.triu(P)), q, sp.csc_matrix(A), l_, u_, verbose=False, eps_abs=1e-8, eps_rel=1e-8,
                max_iter=100000, polish=True)
        res = m.solve()
        solved.append(res.info.status in ("solved", "solved inaccurate"))
        ref_l.append(res.x[:T] if solved[-1] else np.full(T, np.nan))
    ref_l, solved = np.asarray(ref_l), np.asarray(solved)
    r = out.pop("_admm")
    ok = np.asarray(r.ok)
    err_a = np.abs(np.asarray(r.l) - ref_l)[solved & ok]
    lb = np.asarray(out.pop("_boxosqp"))
    err_b = np.abs(lb - ref_l)[solved]
    out.update({"frames": n, "points": T, "osqp_solved_share": float(solved.mean()),
                "admm_ok_share_on_solved": float(ok[solved].mean()),
                "admm_infeasible_agrees": float(np.mean(np.asarray(r.feasible) == solved)),
                "admm_max_err_m": float(err_a.max()) if err_a.size else float("nan"),
                "admm_p99_err_m": float(np.percentile(err_a, 99)) if err_a.size else float("nan"),
                "boxosqp_tol": box_tol,
                "boxosqp_max_err_m": float(np.nanmax(err_b)) if err_b.size else float("nan"),
                "boxosqp_p99_err_m": float(np.nanpercentile(err_b, 99)) if err_b.size else float("nan"),
                "admm_iterations_median": float(np.median(np.asarray(r.iterations))),
                "admm_polished_share_on_solved": float(np.asarray(r.polished)[solved].mean())})
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 100, 10000])
    ap.add_argument("--obstacles", type=int, default=32)
    ap.add_argument("--chunk", type=int, default=250)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--radius", type=float, default=12.0)
    ap.add_argument("--methods", nargs="+", default=["contour", "exact", "slbox", "centerline"])
    ap.add_argument("--baseline-batches", type=int, nargs="+", default=[1, 100],
                    help="batch sizes for the slow baselines (slbox, centerline: they project every corner)")
    ap.add_argument("--qp-frames", type=int, default=50)
    ap.add_argument("--box-vmap-frames", type=int, default=10, help="frames of the vmapped BoxOSQP timing (0: skip)")
    ap.add_argument("--qp-points", type=int, default=81)
    ap.add_argument("--qp-ds", type=float, default=1.0)
    ap.add_argument("--box-tol", type=float, default=1e-4)
    ap.add_argument("--out", default="results/bench_bounds.json")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    pool = min(max(args.batches), args.chunk)
    refs, S, L, OBS, _, _ = make_scenarios(rng, pool, args.obstacles, radii=(args.radius,))
    ref = reference_line(jnp.asarray(refs[0]))
    S, L, OBS = jnp.asarray(S[0]), jnp.asarray(L[0]), jnp.asarray(OBS[0])
    res = {"device": str(jax.devices()[0]), "cpu_count": os.cpu_count(), "machine": platform.machine(),
           "points_per_frame": int(S.shape[-1]), "obstacles": args.obstacles, "radius_m": args.radius,
           "load_average_1min": round(os.getloadavg()[0], 2),
           "frames_per_s": {}}
    for method in args.methods:
        fn = jax.jit(lambda s, l, o, m=method: path_bounds(ref, s, l, CAR, o, lane_lower=-LANE, lane_upper=LANE,
                                                           method=m, rectangles=True))
        for n in (args.baseline_batches if method in ("slbox", "centerline") else args.batches):
            c = min(n, args.chunk)
            xs = (S[:c], L[:c], OBS[:c])
            t = time.perf_counter()
            b = jax.block_until_ready(fn(*xs))
            res[f"{method}_compile_s_batch{c}"] = round(time.perf_counter() - t, 3)
            chunks = -(-n // c)
            dt = best_time(lambda: [jax.block_until_ready(fn(*xs)) for _ in range(chunks)], args.reps)
            fps = round(chunks * c / dt, 1)
            res[f"{method}_frames_per_s"] = {**res.get(f"{method}_frames_per_s", {}), str(n): fps}
            if method == "contour":
                res["frames_per_s"][str(n)] = fps
                ov = np.asarray(b.overlap)
                res["contour_constructed_share_of_overlaps"] = round(
                    float(1 - np.mean(np.asarray(b.case)[ov] == CASE_UNCONSTRUCTED)), 4)
            print(f"{method:10s} batch {n:6d}: {fps:10.1f} frames/s "
                  f"(compile {res[f'{method}_compile_s_batch{c}']:.1f} s)", flush=True)
    write_figures(res, args.out)
    if args.qp_frames:
        res["path_qp"] = qp_bench(args.qp_frames, args.qp_points, args.qp_ds, args.reps, args.box_tol,
                                  args.box_vmap_frames)
        print("path QP:", json.dumps(res["path_qp"]), flush=True)
        write_figures(res, args.out)
    return res


if __name__ == "__main__":
    main()
