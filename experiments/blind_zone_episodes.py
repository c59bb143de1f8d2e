"""Where the blind-zone time of a drive comes from (seed 001 on recorded traffic).

Reads a ``jaxplan drive`` output folder (one ``driven.json`` per scenario) and the scenario
folder it drove, and splits the time the car's box spent in a moving neighbour's blind zone
(the speed suite's measure, ``jaxplan.eval.speed_suite``) into episodes per neighbour:
those already under way at the start of the drive (step <= 2) and the later ones, which
are split by who passes whom at the episode's first step (the neighbour faster than the
car: it overtakes the car, which can only leave its zone by braking hard or speeding).

    python experiments/blind_zone_episodes.py R/shared-pathspeed ../shared/data/commonroad2018a [--out F.json]
"""
from __future__ import annotations

import argparse
import json
import os

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.planner import SIM_VEHICLE
from jaxplan.eval.speed_suite import _blind_zone_steps
from jaxplan.eval.timing import write_figures
from jaxplan.scenarios.batch import stack_scenes
from jaxplan.scenarios.files import load_records
from jaxplan.speed import SpeedConfig
from jaxplan.speed.nonblocking import obstacle_speed

START_STEPS = 2


def episodes(steps: np.ndarray) -> list:
    """Runs of consecutive step indices ``[(first, length), ...]``."""
    if not len(steps):
        return []
    parts = np.split(steps, np.nonzero(np.diff(steps) > 1)[0] + 1)
    return [(int(p[0]), len(p)) for p in parts]


def drive_episodes(states: np.ndarray, scene, dt: float, sp: SpeedConfig) -> list:
    """Blind-zone episodes of one drive, per moving neighbour: dicts with ``first``, ``steps``
    and ``dv`` (neighbour speed minus the car's at the first step, m/s)."""
    N = len(states)
    b = stack_scenes([scene], min_steps=N + 1)
    obs = jax.vmap(lambda o: o.window(0, N))(b.obstacles)
    moving = np.asarray(jax.vmap(obstacle_speed)(obs)) > sp.v_moving  # (1, K)
    boxes = np.asarray(obs.boxes)[0]
    xs = [jnp.asarray(states[None, :, i]) for i in (1, 2, 3)]
    out = []
    for k in np.nonzero(moving[0])[0]:
        only = np.zeros_like(moving)
        only[0, k] = True
        hit = np.asarray(_blind_zone_steps(*xs, jnp.ones((1, N), bool), obs.boxes, obs.valid, jnp.asarray(only),
                                           float(SIM_VEHICLE.length), float(SIM_VEHICLE.width), sp.blind_back,
                                           sp.blind_front))[0]
        for first, n in episodes(np.nonzero(hit)[0]):
            j = min(first + 1, N - 1)
            v_nb = np.linalg.norm(boxes[k, j, :2] - boxes[k, j - 1, :2]) / dt if j > 0 else 0.0
            out.append({"neighbour": int(k), "first": first, "steps": n, "dv": float(v_nb - states[first, 4])})
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("drives", help="a jaxplan drive output folder (one folder per scenario with driven.json)")
    ap.add_argument("scenarios", help="the scenario folder it drove")
    ap.add_argument("--out", default="results/blind_zone_episodes.json")
    args = ap.parse_args(argv)
    for p in (args.drives, args.scenarios):
        if not os.path.isdir(p):
            raise SystemExit(f"blind_zone_episodes: {p}: not a folder")
    sp = SpeedConfig()
    rows, dt = [], 0.1
    for name in sorted(os.listdir(args.scenarios)):
        stem, ext = os.path.splitext(name)
        f = os.path.join(args.drives, stem, "driven.json")
        if ext not in (".json", ".xml") or not os.path.exists(f):
            continue
        d = json.load(open(f))
        dt = float(d["dt"])
        rec = load_records([os.path.join(args.scenarios, name)])[0]
        for e in drive_episodes(np.asarray(d["states"]), rec.scene, dt, sp):
            rows.append({"scenario": stem, **e})
    at_start = [r for r in rows if r["first"] <= START_STEPS]
    later = [r for r in rows if r["first"] > START_STEPS]
    res = {"drives": args.drives, "episodes": len(rows),
           "blind_s_per_neighbour_total": round(sum(r["steps"] for r in rows) * dt, 2),
           "at_start": len(at_start), "at_start_s": round(sum(r["steps"] for r in at_start) * dt, 2),
           "later": len(later), "later_s": round(sum(r["steps"] for r in later) * dt, 2),
           "later_neighbour_faster": sum(r["dv"] > 0 for r in later),
           "later_neighbour_slower": sum(r["dv"] <= 0 for r in later),
           "median_episode_s": float(np.median([r["steps"] for r in rows]) * dt) if rows else None}
    write_figures(res, args.out, extra={"rows": rows})
    return res


if __name__ == "__main__":
    main()
