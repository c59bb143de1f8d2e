"""``jaxplan parkout`` on held-out scene files, judged by shapely.

Writes scene files of the families ``standard`` (road on the left), ``right``, ``wall`` and
``stopped`` (both sides) with spare slot length (front gap + rear gap) drawn in ``--spare``,
runs the command on each file (``jaxplan.cli.main``, in this process) and checks every driven
state of ``parkout.json`` against the file's obstacle polygons with shapely (the car's box at the
box-centre state). Prints the figures and writes ``OUT/heldout.json``.

    python experiments/parkout_heldout.py [--n 50] [--seed 20240917] [--spare 1.5 3.0] [--out results/parkout_heldout]
"""
from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
import shapely

from jaxplan.cli import main as jaxplan_main
from jaxplan.parking.families import family_scenes, scene_dicts
from jaxplan.types import VehicleParams


def car_box(state, vehicle):
    x, y, h = state[:3]
    c, s = np.cos(h), np.sin(h)
    hl, hw = vehicle.length / 2, vehicle.width / 2
    loc = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
    return shapely.Polygon(np.array([x, y]) + loc @ np.array([[c, s], [-s, c]]))


def judge(scene: dict, result: dict, vehicle) -> dict:
    obstacles = [shapely.Polygon(o["polygon"]).buffer(0) for o in scene["obstacles"]]
    tree = shapely.STRtree(obstacles)
    states = np.asarray(result["states"], float)
    overlap = 0.0
    clearance = np.inf
    for st in states:
        box = car_box(st, vehicle)
        for j in tree.query(box, predicate="intersects"):
            overlap = max(overlap, box.intersection(obstacles[j]).area)
        near = tree.query_nearest(box, return_distance=True)[1]
        clearance = min(clearance, float(near.min()) if len(near) else np.inf)
    step = np.linalg.norm(np.diff(states[:, :2], axis=0), axis=1).max() if len(states) > 1 else 0.0
    return {"collision": overlap > 1e-9, "overlap_m2": overlap, "clearance_m": clearance, "max_step_m": float(step)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=50, help="scene files per family")
    ap.add_argument("--seed", type=int, default=20240917)
    ap.add_argument("--spare", type=float, nargs=2, default=(1.5, 3.0), help="range of front + rear gap [m]")
    ap.add_argument("--plots", type=int, default=2, help="plots per family")
    ap.add_argument("--out", default="results/parkout_heldout")
    args = ap.parse_args(argv)
    car = VehicleParams()
    rng = np.random.default_rng(args.seed)
    os.makedirs(os.path.join(args.out, "scenes"), exist_ok=True)
    summary, rows = {}, []
    t0 = time.perf_counter()
    for fam in ("standard", "right", "wall", "stopped"):
        sc, info = family_scenes(fam, rng, args.n, car, spare=tuple(args.spare))
        dicts = scene_dicts(sc, info, car, rng)
        res = []
        for i, d in enumerate(dicts):
            name = f"{fam}_{i:03d}"
            path = os.path.join(args.out, "scenes", name + ".json")
            with open(path, "w") as f:
                json.dump(d, f)
            out = os.path.join(args.out, "runs", name)
            argv = ["parkout", path, "--out", out] + ([] if i < args.plots else ["--no-plot"])
            rc = jaxplan_main(argv)
            with open(os.path.join(out, "parkout.json")) as f:
                r = json.load(f)
            j = judge(d, r, car)
            res.append(dict(name=name, rc=rc, side=d["side"], spare=float(info["spare"][i]), success=r["success"],
                            moves=r["moves"], **j))
        ok = np.array([r["success"] and not r["collision"] for r in res])
        summary[fam] = {"files": len(res), "exit_0": int(sum(r["rc"] == 0 for r in res)),
                        "success_rate": float(ok.mean()),
                        "collisions": int(sum(r["collision"] for r in res)),
                        "sides": {s: int(sum(r["side"] == s for r in res)) for s in ("left", "right")},
                        "moves_mean": float(np.mean([r["moves"] for r in res if r["success"]] or [np.nan])),
                        "clearance_min_m": float(min(r["clearance_m"] for r in res)),
                        "max_state_step_m": float(max(r["max_step_m"] for r in res)),
                        "spare_of_failures_m": [round(r["spare"], 3) for r in res if not r["success"]]}
        rows += res
        print(fam, json.dumps(summary[fam]), flush=True)
    summary["all"] = {"files": len(rows), "collisions": int(sum(r["collision"] for r in rows)),
                      "success_rate": float(np.mean([r["success"] and not r["collision"] for r in rows])),
                      "spare_range_m": list(args.spare), "seed": args.seed, "wall_s": time.perf_counter() - t0}
    with open(os.path.join(args.out, "heldout.json"), "w") as f:
        json.dump({"summary": summary, "runs": rows}, f, indent=1)
    print(json.dumps(summary["all"]))
    print(f"wrote {os.path.join(args.out, 'heldout.json')}")


if __name__ == "__main__":
    main()
