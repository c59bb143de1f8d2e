"""Benchmark: path bounds for 20-point frames against 32 obstacles, and the path QP.

Frames per second of ``path_bounds`` (contour, exact, centre-line) for batches
of 1, 100 and 10,000 frames (large batches run in chunks of ``--chunk`` frames
through one compiled function), compile time separate; and the time to plan
inside the bounds (piecewise-jerk QP, qpax) per frame. Writes JSON.

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

from jaxplan.bounds.frenet_bounds import path_bounds
from jaxplan.bounds.optimize import optimize_path
from jaxplan.eval.bounds_suite import CAR, LANE, make_scenarios
from jaxplan.geometry import reference_line
from jaxplan.eval.timing import best_time



def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 100, 10000])
    ap.add_argument("--obstacles", type=int, default=32)
    ap.add_argument("--chunk", type=int, default=250)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--radius", type=float, default=12.0)
    ap.add_argument("--methods", nargs="+", default=["contour", "exact", "centerline"])
    ap.add_argument("--out", default="results/bench_bounds.json")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    pool = min(max(args.batches), args.chunk)
    refs, S, L, OBS, _ = make_scenarios(rng, pool, args.obstacles, radii=(args.radius,))
    ref = reference_line(jnp.asarray(refs[0]))
    S, L, OBS = jnp.asarray(S[0]), jnp.asarray(L[0]), jnp.asarray(OBS[0])
    res = {"device": str(jax.devices()[0]), "cpu_count": os.cpu_count(), "machine": platform.machine(),
           "points_per_frame": int(S.shape[-1]), "obstacles": args.obstacles, "radius_m": args.radius,
           "note": "shared 2-core machine with other jobs running: timings are indicative"}
    for method in args.methods:
        fn = jax.jit(lambda s, l, o, m=method: path_bounds(ref, s, l, CAR, o, lane_lower=-LANE,
                                                           lane_upper=LANE, method=m))
        for n in args.batches:
            c = min(n, args.chunk)
            xs = (S[:c], L[:c], OBS[:c])
            t = time.perf_counter()
            jax.block_until_ready(fn(*xs))
            res[f"{method}_compile_s_batch{c}"] = round(time.perf_counter() - t, 3)
            chunks = -(-n // c)
            dt = best_time(lambda: [jax.block_until_ready(fn(*xs)) for _ in range(chunks)], args.reps)
            res[f"{method}_frames_per_s_batch{n}"] = round(chunks * c / dt, 1)
            print(f"{method:10s} batch {n:6d}: {chunks * c / dt:10.1f} frames/s "
                  f"(compile {res[f'{method}_compile_s_batch{c}']:.1f} s)", flush=True)
    # Planning inside the contour bounds.
    b = jax.jit(lambda s, l, o: path_bounds(ref, s, l, CAR, o, lane_lower=-LANE, lane_upper=LANE))(S, L, OBS)
    ds = float(S[0, 1] - S[0, 0])
    init = jnp.stack([L[:, 0], jnp.zeros_like(L[:, 0]), jnp.zeros_like(L[:, 0])], -1)
    qp = jax.jit(lambda lo, up, lr, i0: optimize_path(lo, up, ds, lr, i0))
    for n in sorted({1, min(100, pool), pool}):
        xs = (b.lower[:n], b.upper[:n], L[:n], init[:n])
        t = time.perf_counter()
        r = jax.block_until_ready(qp(*xs))
        res[f"qp_compile_s_batch{n}"] = round(time.perf_counter() - t, 3)
        dt = best_time(lambda: jax.block_until_ready(qp(*xs)), args.reps)
        res[f"qp_ms_per_frame_batch{n}"] = round(1e3 * dt / n, 4)
        res[f"qp_ok_share_batch{n}"] = float(np.mean(np.asarray(r.ok)))
        print(f"path QP    batch {n:6d}: {1e3 * dt / n:8.3f} ms/frame, ok {np.mean(np.asarray(r.ok)):.2f}", flush=True)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(res, f, indent=1)
    print(json.dumps(res, indent=1))
    return res


if __name__ == "__main__":
    main()
