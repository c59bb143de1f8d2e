"""Benchmark: complete park-out plans (drive / re-plan loop to the end) per second.

Batches of 1 / 100 / 1,000 scenes in one jitted call each; compile time is
reported separately. Prints figures and writes JSON (``--out``).

    python experiments/bench_parkout.py [--sizes 1 100 1000] [--reps 3] [--out results/bench_parkout.json]
"""
from __future__ import annotations

import argparse
import os
import platform

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.parking import ParkoutConfig, make_scenes, park_out
from jaxplan.types import VehicleParams
from jaxplan.eval.timing import best_time, timed, write_figures


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 100, 1000])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--out", default="results/bench_parkout.json")
    args = ap.parse_args(argv)
    car, cfg = VehicleParams(), ParkoutConfig()
    res = {"device": str(jax.devices()[0]), "cpu_count": os.cpu_count(), "machine": platform.machine(),
           "max_moves": cfg.max_moves, "steps": cfg.steps}
    for n in args.sizes:
        rng = np.random.default_rng(n)
        scene, _ = make_scenes(rng, n, car, front_gap=rng.uniform(0.5, 2.5, n), rear_gap=rng.uniform(0.5, 2.5, n),
                               heading_noise_deg=1.5, offset_noise=0.1, edge_noise=0.03, salt=1e-5)
        key = jnp.asarray([0, 1], jnp.uint32)
        out, first = timed(lambda: jax.block_until_ready(park_out(scene, key, cfg, car)))
        best = best_time(lambda: jax.block_until_ready(park_out(scene, jnp.asarray([3, 1], jnp.uint32), cfg, car)),
                         args.reps)
        res[f"batch_{n}_plans_per_s"] = n / best
        res[f"batch_{n}_seconds"] = best
        res[f"batch_{n}_compile_s"] = max(first - best, 0.0)
        res[f"batch_{n}_success_rate"] = float(np.mean(np.asarray(out.success)))
        res[f"batch_{n}_moves_mean"] = float(np.mean(np.asarray(out.moves)))
        print(f"batch {n:5d}: {n / best:9.1f} complete plans/s ({best:.3f} s per call, compile {first - best:.1f} s, "
              f"success {res[f'batch_{n}_success_rate']:.2f}, moves {res[f'batch_{n}_moves_mean']:.2f})", flush=True)
    write_figures(res, args.out)


if __name__ == "__main__":
    main()
