"""Benchmark: complete park-out plans (every move, to the end) per second, planning timed apart from
rendering the grids.

The scenes are the same mix as before this planner had a search (slots with front and rear gaps
U(0.5, 2.5) m, heading noise 1.5 deg, grid edge noise 3 cm, false positives): most leave with the
two reference curves, a few need the search, and hopeless ones stop early. Planning starts from the
occupancy grids (``plan_grids``: cell tables, two-curve loop with lane refill, search for the failures);
rendering (``render_scenes``) is timed on its own. Compile time is reported apart. ``--families``
adds the planning rate of each scene family at the largest batch. Prints figures and writes JSON
(``--out``), ``plans_per_s`` keyed by batch size.

    python experiments/bench_parkout.py [--sizes 1 100 1000] [--reps 3] [--devices 2] [--families] [--out results/bench_parkout.json]

``--devices N`` splits the host CPU into N XLA devices (``--xla_force_host_platform_device_count``;
default: the number of cores), and the driver sends its chunks of scenes to them round-robin.
Besides wall time the JSON holds the process CPU time per plan (``cpu_ms_per_plan``), a figure
that other jobs on the machine disturb less.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time


def _early_devices(argv):
    """``--devices`` must take effect before jax is imported."""
    args = sys.argv[1:] if argv is None else argv
    n = os.cpu_count() or 1
    if "--devices" in args:
        n = int(args[args.index("--devices") + 1])
    if n > 1 and "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={n}")
    return n


_early_devices(None)

import jax  # noqa: E402
import numpy as np  # noqa: E402

from jaxplan.eval.timing import best_time, timed  # noqa: E402
from jaxplan.parking import ParkoutConfig, make_scenes, plan_grids, render_scenes  # noqa: E402
from jaxplan.parking.families import FAMILIES, family_scenes  # noqa: E402
from jaxplan.types import VehicleParams  # noqa: E402


def _mix(n, car, seed):
    rng = np.random.default_rng(seed)
    return make_scenes(rng, n, car, front_gap=rng.uniform(0.5, 2.5, n), rear_gap=rng.uniform(0.5, 2.5, n),
                       heading_noise_deg=1.5, offset_noise=0.1, edge_noise=0.03, salt=1e-5)[0]


def _measure(scene, car, cfg, reps):
    grids, r_first = timed(lambda: jax.block_until_ready(render_scenes(scene, 1, cfg, car)))
    r_best = best_time(lambda: jax.block_until_ready(render_scenes(scene, 2, cfg, car).cells), reps)
    out, p_first = timed(lambda: plan_grids(scene.start, grids, cfg, car))
    c0 = time.process_time()
    p_best = best_time(lambda: plan_grids(scene.start, grids, cfg, car), reps)
    cpu = (time.process_time() - c0) / max(1, reps)
    return out, r_first, r_best, p_first, p_best, cpu


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 100, 1000])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--families", action="store_true", help="also time each scene family at the largest size")
    ap.add_argument("--devices", type=int, default=os.cpu_count(), help="XLA host devices (default: cores)")
    ap.add_argument("--out", default="results/bench_parkout.json")
    args = ap.parse_args(argv)
    car, cfg = VehicleParams(), ParkoutConfig()
    res = {"device": str(jax.devices()[0]), "cpu_count": os.cpu_count(), "machine": platform.machine(),
           "devices": len(jax.local_devices()),
           "load_average_at_start": [round(x, 2) for x in os.getloadavg()], "max_moves": cfg.max_moves,
           "grid_cells": cfg.rows * cfg.cols}
    keys = ("plans_per_s", "plan_s", "cpu_ms_per_plan", "render_s", "render_ms_per_scene", "plans_per_s_with_render",
            "compile_s", "success_rate", "moves_mean", "searched_share")
    for k in keys:
        res[k] = {}
    for n in args.sizes:
        scene = _mix(n, car, n)
        out, r_first, r_best, p_first, p_best, cpu = _measure(scene, car, cfg, args.reps)
        b = str(n)
        res["plans_per_s"][b] = n / p_best
        res["plan_s"][b] = p_best
        res["cpu_ms_per_plan"][b] = 1e3 * cpu / n
        res["render_s"][b] = r_best
        res["render_ms_per_scene"][b] = 1e3 * r_best / n
        res["plans_per_s_with_render"][b] = n / (p_best + r_best)
        res["compile_s"][b] = max(p_first - p_best, 0.0) + max(r_first - r_best, 0.0)
        res["success_rate"][b] = float(np.mean(out.success))
        res["moves_mean"][b] = float(np.mean(out.moves))
        res["searched_share"][b] = float(np.mean(out.searched))
        print(f"batch {n:5d}: {n / p_best:8.1f} plans/s planning ({p_best:.3f} s, {1e3 * cpu / n:.2f} ms CPU per plan), "
              f"render {1e3 * r_best / n:.2f} ms "
              f"per scene, success {res['success_rate'][b]:.3f}, moves {res['moves_mean'][b]:.2f}, "
              f"searched {res['searched_share'][b]:.3f}", flush=True)
    if args.families:
        n = max(args.sizes)
        res["family_plans_per_s"] = {}
        res["family_success_rate"] = {}
        for i, fam in enumerate(FAMILIES):
            scene, _ = family_scenes(fam, np.random.default_rng([n, i]), n, car)
            out, _, _, _, p_best, _ = _measure(scene, car, cfg, 1)
            res["family_plans_per_s"][fam] = n / p_best
            res["family_success_rate"][fam] = float(np.mean(out.success))
            print(f"family {fam:9s}: {n / p_best:8.1f} plans/s, success {np.mean(out.success):.3f}", flush=True)
    res["load_average_at_end"] = [round(x, 2) for x in os.getloadavg()]
    res["note"] = ("timings are wall clock on a machine other jobs may share; compare load_average_* with cpu_count"
                   f" (run at {time.strftime('%Y-%m-%d %H:%M')})")
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(res, f, indent=1)
    print(json.dumps(res, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
