"""Benchmark: ST-graph speed plans per second (7 s horizon, 20 obstacles), batch 1 / 100 / 1,000.

Every plan builds the path profile, the blocking and non-blocking ST boundaries of 20
moving obstacles (boxes every 0.1 s, resampled to the DP's sub-steps), the stage costs
and runs the exact DP with backtracking. Compile time is reported separately. Also
times coarser / finer grids (the DP's cost grows with stations x speeds x accelerations).
Apollo's DP uses a 1 s time grid and a dense 0.1 m station grid near the car.

    python experiments/bench_speed.py [--batches 1 100 1000] [--out results/bench_speed.json]
"""
from __future__ import annotations

import argparse
import json
import os
import platform

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.frenet import reference_line
from jaxplan.speed import CostWeights, SpeedConfig, plan_speed
from jaxplan.types import Obstacles
from jaxplan.eval.timing import best_time, timed

K = 20


def scenes(rng, B, horizon):
    """B random straight-road scenes with K obstacles in three lanes (some crossing)."""
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


def bench(cfg, B, reps, rng):
    refs, obs, v0 = scenes(rng, B, cfg.horizon)
    w = CostWeights.default()
    kc = (jnp.zeros((B, 1, 4, 2)), jnp.ones((B, 1, 4), bool), jnp.zeros((B, 1), bool))
    run = lambda: jax.block_until_ready(plan_speed(refs, obs, cfg, w, v0=v0, s0=20.0, keep_clear=kc))
    p, compile_s = timed(run)
    best = best_time(run, reps)
    return {"batch": B, "plans_per_s": B / best, "ms_per_call": 1e3 * best, "compile_s": compile_s,
            "feasible": float(np.mean(np.asarray(p.feasible)))}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 100, 1000])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--out", default="results/bench_speed.json")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    grids = {
        "dt1_ds1 (default)": SpeedConfig(),
        "dt1_ds2 (coarse)": SpeedConfig(ds=2.0, a_min=-6.0, a_max=2.0),
        "dt1_ds0.5 (fine)": SpeedConfig(ds=0.5),
        "dt0.5_ds0.5": SpeedConfig(dt=0.5, n_t=14, ds=0.5, a_min=-6.0, a_max=2.0, n_sub=3),
    }
    res = {"obstacles": K, "horizon_s": 7.0, "device": str(jax.devices()[0]), "cpu_count": os.cpu_count(),
           "machine": platform.machine(), "grids": {}}
    for name, cfg in grids.items():
        info = {"dt": cfg.dt, "ds": cfg.ds, "dv": cfg.dv, "da": cfg.da, "stations": cfg.n_s, "speeds": cfg.n_v,
                "accels": len(cfg.accel_offsets), "states_per_step": cfg.n_s * cfg.n_v * len(cfg.accel_offsets),
                "runs": []}
        batches = args.batches if name.startswith("dt1_ds1 ") else [b for b in args.batches if b <= 100]
        for B in batches:
            r = bench(cfg, B, args.reps, rng)
            info["runs"].append(r)
            print(f"{name:18s} states/step {info['states_per_step']:7d}  batch {B:5d}: "
                  f"{r['plans_per_s']:9.1f} plans/s  ({r['ms_per_call']:.1f} ms/call, compile {r['compile_s']:.1f} s)",
                  flush=True)
        res["grids"][name] = info
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(res, f, indent=1)  # nested: printed above, run by run
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
