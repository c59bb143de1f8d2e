"""Batch evaluation at scale.

Two modes:

``scenes``  the lattice planner over N synthetic road scenes (``jaxplan.scenarios.synthetic``),
            in chunks, each chunk sharded over every local device (``jaxplan.eval.batch``);
            resumable (kill it and run it again: finished chunks are kept). Prints time,
            scenes/s, time per scene and peak memory, and writes them to OUT/scaling.json::

                python experiments/batch_eval.py scenes --n 10000 --out /tmp/batch

            ``--scaling`` runs 1e2, 1e3, 1e4 and 1e5 scenes, each in a fresh process
            (so peak memory is per run), and prints the table.

``suites``  every suite that takes recorded traffic over a scenario folder, then the report::

                python experiments/batch_eval.py suites --scenarios ../shared/data/commonroad2018a --out /tmp/real

Several devices: ``XLA_FLAGS=--xla_force_host_platform_device_count=4`` on a CPU, or all
GPUs of a host. Several hosts: set ``JAXPLAN_COORDINATOR=host:port``,
``JAXPLAN_NUM_PROCESSES`` and ``JAXPLAN_PROCESS_ID`` on each (``jax.distributed``);
each process runs its share of the chunks into the same (shared) output folder.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.eval.batch import load_results, maybe_init_distributed, peak_rss_mb, run_chunked, sharded_map
from jaxplan.geometry.frenet import reference_line
from jaxplan.lattice import CostWeights, LatticeConfig, PlanState, plan_batch
from jaxplan.scenarios.synthetic import road_scenes
from jaxplan.types import Obstacles

CONFIG = LatticeConfig()
SEED_STRIDE = 1_000_003  # scene i of a run is generated from seed (seed * stride + i) per chunk


@jax.jit
def plan_chunk(batch):
    """Lattice plan of every scene of a chunk; per-scene summary figures."""
    res = plan_batch(PlanState.from_rows(batch["ego"]), jax.vmap(reference_line)(batch["ref_xy"]),
                     Obstacles(batch["boxes"], batch["valid"], batch["t"], batch["static"]), CONFIG, CostWeights())
    idx = res.chosen[:, None]
    pick = lambda a: jnp.take_along_axis(a, idx, axis=1)[:, 0]
    return {"chosen": res.chosen, "mode": res.mode, "chosen_collides": pick(res.collided),
            "chosen_min_sep": pick(res.min_sep.min(-1)), "free_candidates": (~res.collided).sum(-1)}


def make_chunk(seed: int):
    def make(start: int, stop: int):
        sc = road_scenes(stop - start, seed=seed * SEED_STRIDE + start)
        f32 = lambda x: np.asarray(x, np.float32)
        return {"ego": f32(sc.ego), "ref_xy": f32(sc.ref_xy), "boxes": f32(sc.boxes), "valid": sc.valid,
                "t": f32(sc.t), "static": sc.static}
    return make


def run_scenes(n: int, out: str, chunk: int, seed: int, fresh: bool = False) -> dict:
    maybe_init_distributed()
    make = make_chunk(seed)
    t0 = time.perf_counter()
    sharded_map(plan_chunk, make(0, 1), pad_to=chunk)  # compile once (same shape and sharding), untimed
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    info = run_chunked(plan_chunk, make, n, out, chunk_size=chunk, progress=True,
                       inputs={"seed": seed, "config": CONFIG, "seed_stride": SEED_STRIDE}, fresh=fresh)
    wall = time.perf_counter() - t0
    res = load_results(out)
    done = len(res.get("chosen", []))
    fig = {"scenes": n, "devices": jax.device_count(), "chunk": chunk, "compile_s": round(compile_s, 2),
           "wall_s": round(wall, 2), "scenes_per_s": round(info["scenes_per_s"], 1),
           "ms_per_scene": round(1e3 * wall / max(1, n - info["chunks_skipped"] * chunk), 4),
           "chunks_run": info["chunks_run"], "chunks_skipped": info["chunks_skipped"],
           "peak_rss_mb": round(peak_rss_mb(), 1), "scenes_in_results": done,
           "chosen_collision_share": float(np.mean(res["chosen_collides"])) if done else None}
    with open(os.path.join(out, "scaling.json"), "w") as f:
        json.dump(fig, f, indent=1)
    return fig


def scaling(out: str, chunk: int, seed: int, sizes=(100, 1000, 10_000, 100_000)) -> list:
    rows = []
    for n in sizes:
        d = os.path.join(out, f"n{n}")
        r = subprocess.run([sys.executable, __file__, "scenes", "--n", str(n), "--out", d, "--chunk",
                            str(min(chunk, n)), "--seed", str(seed), "--no-fresh"], capture_output=True, text=True)
        if r.returncode != 0:
            raise SystemExit(r.stderr[-2000:])
        rows.append(json.load(open(os.path.join(d, "scaling.json"))))
        print(json.dumps(rows[-1]), flush=True)
    base = rows[1]["ms_per_scene"] if len(rows) > 1 else rows[0]["ms_per_scene"]
    print("\n| scenes | wall s | scenes/s | ms/scene | vs 1e3 | peak RSS MiB |")
    print("| --- | --- | --- | --- | --- | --- |")
    for r in rows:
        print(f"| {r['scenes']} | {r['wall_s']} | {r['scenes_per_s']} | {r['ms_per_scene']} | "
              f"{r['ms_per_scene'] / base:.2f} | {r['peak_rss_mb']} |")
    with open(os.path.join(out, "scaling_table.json"), "w") as f:
        json.dump(rows, f, indent=1)
    return rows


def suites(scenarios: str, out: str, quick: bool) -> dict:
    """Every suite that reads recorded traffic (``--scenarios``), in one run, then ``report.md``."""
    from jaxplan.eval.registry import SuiteArgs, run_suite
    from jaxplan.eval.report import write_report
    from jaxplan.scenarios.loader import scenario_files

    n_files = len(scenario_files(scenarios))
    names = ("lattice", "speed", "tune")
    m = run_suite(",".join(names), SuiteArgs(out=out, scenarios=scenarios, quick=quick))
    figures = {}
    for name in names:
        wall = m[f"{name}.wall_s"]
        figures[name] = {"wall_s": round(wall, 1), "s_per_scenario": round(wall / n_files, 3),
                         "scenarios_per_s": round(n_files / wall, 3), "skipped_files": m.get(f"{name}.skipped_files")}
        print(name, figures[name], flush=True)
    write_report(out)
    with open(os.path.join(out, "batch_suites.json"), "w") as f:
        json.dump({"scenario_files": n_files, **figures}, f, indent=1)
    return figures


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="mode", required=True)
    s = sub.add_parser("scenes")
    s.add_argument("--n", type=int, default=1000)
    s.add_argument("--chunk", type=int, default=2048)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--out", default="/tmp/jaxplan_batch")
    s.add_argument("--scaling", action="store_true", help="1e2 .. 1e5 scenes, one process each")
    s.add_argument("--fresh", action="store_true", help="delete the chunks of an earlier run in --out first")
    s.add_argument("--no-fresh", action="store_true", help=argparse.SUPPRESS)
    r = sub.add_parser("suites")
    r.add_argument("--scenarios", required=True)
    r.add_argument("--out", default="/tmp/jaxplan_real")
    r.add_argument("--quick", action="store_true")
    a = p.parse_args(argv)
    if a.mode == "suites":
        suites(a.scenarios, a.out, a.quick)
    elif a.scaling:
        scaling(a.out, a.chunk, a.seed)
    else:
        try:
            print(json.dumps(run_scenes(a.n, a.out, a.chunk, a.seed, a.fresh), indent=1))
        except ValueError as e:
            raise SystemExit(f"batch_eval: error: {e}") from None


if __name__ == "__main__":
    main()
