"""Held-out-location figures of the imitation cost and the speed planner's weights through the
soft DP, on a folder of recorded scenarios; prints JSON and writes it to ``--out``.

    PYTHONPATH=$PWD python experiments/tune_heldout.py /work/shared/data/commonroad2018a --out heldout.json

``locations``: ``jaxplan.tuning.run.held_out_locations`` (trained on every other location,
figures on each held-out one: ``{location}.{method}.ade3`` ...). ``speed``:
``jaxplan.tuning.run.tune_speed`` on the split disjoint by vehicle (station errors along the
human path). The same figures as ``jaxplan eval tune --scenarios DIR`` without ``--quick``,
without its plots and its vehicle-split lattice run (``jaxplan tune lattice`` prints that one).
"""
from __future__ import annotations

import argparse
import json
import sys
import time


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scenarios")
    p.add_argument("--out", required=True)
    p.add_argument("--steps", type=int, help="optimiser steps of the imitation cost (default run.RECORDED_STEPS)")
    p.add_argument("--lr", type=float, help="its learning rate (default run.RECORDED_LR)")
    p.add_argument("--speed-steps", type=int, default=40)
    p.add_argument("--skip", choices=("locations", "speed"), action="append", default=[])
    args = p.parse_args(argv)
    from jaxplan.tuning.run import held_out_locations, recorded_set, split, tune_speed

    ds = recorded_set(args.scenarios)
    out = {"demos": len(ds)}
    if "speed" not in args.skip:
        t0 = time.time()
        train, val = split(ds)
        out.update({f"speed.{k}": v for k, v in tune_speed(train, val, steps=args.speed_steps).metrics.items()})
        out["speed.wall_s"] = time.time() - t0
        _write(out, args.out)
    if "locations" not in args.skip:
        t0 = time.time()
        kw = {k: v for k, v in (("steps", args.steps), ("lr", args.lr)) if v is not None}
        out.update({f"heldout_location.{k}": v for k, v in held_out_locations(ds, **kw).items()})
        out["heldout_location.wall_s"] = time.time() - t0
    _write(out, args.out)
    return 0


def _write(out: dict, path: str) -> None:
    """Print the figures so far and write them to ``path`` (each part as soon as it is done)."""
    out = {k: float(v) if hasattr(v, "__float__") else v for k, v in out.items()}
    with open(path, "w") as f:
        json.dump(out, f, indent=1, sort_keys=True)
    json.dump(out, sys.stdout, indent=1, sort_keys=True)
    print(f"\nwrote {path}", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
