"""Benchmark: the jaxplan lattice against Frenetix (C++ Frenet sampler) on the same work.

Both sample N end speeds x lateral offsets (quintic lateral paths, 3 s at dt = 0.1 s,
31 samples), map them to Cartesian along the same straight reference line and score
them: (a) kinematic costs only, (b) plus K moving obstacles (jaxplan: exact box SAT
per step with collision flags and TTC; Frenetix: its fast collision-probability cost
from the predicted poses). Throughput in trajectories/s, best of ``--reps``; the
ratios come from this one run. jaxplan's compile time is reported separately.
The machine may be shared: timings are noisy, compare ratios.

    python experiments/bench_lattice.py [--sizes 1000 5000 50000] [--obstacles 20]
                                        [--out results/bench_lattice.json]
"""
from __future__ import annotations

import argparse
import itertools
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry import ReferenceLine
from jaxplan.lattice import CostWeights, LatticeConfig, PlanState
from jaxplan.lattice.plan import _plan_jit
from jaxplan.types import Obstacles
from jaxplan.eval.timing import best_time, write_figures

HORIZON, DT, V0 = 3.0, 0.1, 15.0


def _grid(n):
    """Speeds x offsets with about n candidates: (V, L)."""
    v = max(2, int(round(np.sqrt(n / 5))))
    return v, n // v


def _obstacles(k, t):
    """k cars on three lanes ahead, driving at 8 m/s: boxes (k, T, 5)."""
    i = np.arange(k)
    x = 20 + 6 * i[:, None] + 8 * t
    y = np.broadcast_to((((i % 3) - 1) * 3.5)[:, None], x.shape)
    return np.stack([x, y, np.full(x.shape, 4.5), np.full(x.shape, 1.8), np.zeros(x.shape)], -1)



def jaxplan_rate(n, k, reps, near_budget=0.25):
    V, L = _grid(n)
    cfg = LatticeConfig(horizon=HORIZON, dt=DT, speed_deltas_kmh=tuple(np.linspace(-36, 36, V).round(4)),
                        escalation=(1.0,), n_offsets=L, offset_span=3.0, near_budget=near_budget)
    ref = ReferenceLine.from_polyline(np.stack([np.linspace(-20, 400, 421), np.zeros(421)], 1))
    st = PlanState.make(0.0, 0.0, 0.0, V0)
    t = np.arange(cfg.n_steps) * DT
    obs = Obstacles(jnp.asarray(_obstacles(k, t), jnp.float32), jnp.ones((k, len(t)), bool),
                    jnp.asarray(t, jnp.float32)) if k else Obstacles.empty(jnp.asarray(t, jnp.float32))
    w = CostWeights()
    run = lambda: jax.block_until_ready(_plan_jit(st, ref, obs, cfg, w))
    t0 = time.perf_counter()
    res = run()
    compile_s = time.perf_counter() - t0
    return cfg.n_candidates / best_time(run, reps), compile_s, cfg.n_candidates, int(np.asarray(res.collided).sum())


def frenetix_rate(n, k, reps):
    import frenetix
    import frenetix.trajectory_functions as tf
    import frenetix.trajectory_functions.cost_functions as cf

    ref = np.stack([np.linspace(-20, 400, 421), np.zeros(421)], 1)
    cs = frenetix.CoordinateSystemWrapper(ref)
    h = frenetix.TrajectoryHandler(dt=DT)
    h.add_function(tf.FillCoordinates(lowVelocityMode=False, initialOrientation=0.0, coordinateSystem=cs,
                                      horizon=int(HORIZON)))
    for c in (cf.CalculateAccelerationCost("acceleration", 1.0), cf.CalculateJerkCost("jerk", 1.0),
              cf.CalculateLateralJerkCost("lateral_jerk", 1.0),
              cf.CalculateDistanceToReferencePathCost("distance_to_reference_path", 1.0),
              cf.CalculateOrientationOffsetCost("orientation_offset", 1.0)):
        h.add_cost_function(c)
    if k:
        t = np.arange(int(round(HORIZON / DT)) + 1) * DT
        boxes = _obstacles(k, t) + np.array([20.0, 0, 0, 0, 0])  # frenetix's s = 0 is the line's start
        cov = np.zeros((6, 6))
        cov[:2, :2] = 0.1 * np.eye(2)
        cov = np.asfortranarray(cov)
        preds = {}
        for i in range(k):
            path = [frenetix.PoseWithCovariance(np.array([b[0] - 20.0, b[1], 0.0]), np.array([0, 0, 0, 1.0]), cov)
                    for b in boxes[i]]
            preds[i] = frenetix.PredictedObject(i, path, 4.5, 1.8)
        h.add_cost_function(cf.CalculateCollisionProbabilityFast("prediction", 1.0, preds, 4.8, 1.9))
    V, L = _grid(n)
    M = np.array(list(itertools.product([0.0], [HORIZON], [20.0], [V0], [0.0], V0 + np.linspace(-10, 10, V), [0.0],
                                        [0.0], [0.0], [0.0], np.linspace(-3, 3, L), [0.0], [0.0])))

    def run():
        h.reset_Trajectories()
        h.generate_trajectories(M, False)
        h.evaluate_all_current_functions(True)

    run()
    return len(M) / best_time(run, reps), len(M)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 5000, 50000])
    ap.add_argument("--obstacles", type=int, default=20)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--out", default="results/bench_lattice.json")
    args = ap.parse_args(argv)
    res = {"device": str(jax.devices()[0]), "cpu_count": os.cpu_count(), "machine": platform.machine(),
           "samples_per_trajectory": int(round(HORIZON / DT)) + 1, "obstacles": args.obstacles}
    try:
        import frenetix  # noqa: F401
        have_fx = True
        res["frenetix_version"] = getattr(frenetix, "__version__", "?")
    except ImportError:
        have_fx = False
        print("frenetix not installed: skipped (pip install frenetix)")
    for n in args.sizes:
        for k, tag in ((0, "kinematic"), (args.obstacles, f"obstacles{args.obstacles}")):
            rate, comp, n_c, n_col = jaxplan_rate(n, k, args.reps)
            res[f"jaxplan_{tag}_N{n}_traj_per_s"] = rate
            res[f"jaxplan_{tag}_N{n}_compile_s"] = comp
            res[f"jaxplan_{tag}_N{n}_candidates"] = n_c
            if k:
                res[f"jaxplan_{tag}_N{n}_collided"] = n_col
            if have_fx:
                fx, n_f = frenetix_rate(n, k, max(1, args.reps // 2 + 1))
                res[f"frenetix_{tag}_N{n}_traj_per_s"] = fx
                res[f"ratio_{tag}_N{n}"] = rate / fx
        if args.obstacles:  # the dense collision check (no broad phase), for reference
            rate, comp, _, _ = jaxplan_rate(n, args.obstacles, args.reps, near_budget=0.0)
            res[f"jaxplan_dense_obstacles{args.obstacles}_N{n}_traj_per_s"] = rate
    write_figures(res, args.out)
    return res


if __name__ == "__main__":
    main()
