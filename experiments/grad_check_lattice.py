"""Gradient of a closed-loop objective by the lattice's cost weights, through ``rollout`` with the
soft selection, against central finite differences of the same smooth rollout (float64).

    python experiments/grad_check_lattice.py --scenes 20 --steps 100 --out grad_check.json
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=20, help="built-in scenes (survivable ones, round robin by kind)")
    ap.add_argument("--steps", type=int, default=100, help="steps of each drive (0.1 s)")
    ap.add_argument("--temperature", type=float, default=1.0, help="the soft selection's temperature")
    ap.add_argument("--h", type=float, default=1e-6,
                    help="relative finite-difference step (a drive is smooth only piecewise: discrete events such as "
                         "a filter flipping or the drive ending bound the step; at 1e-4 some weights straddle one)")
    ap.add_argument("--weights", default="alpha,beta,delta,jerk_lon,obstacle,v_offset,goal", help="cost weights to check")
    ap.add_argument("--out", default=None, help="JSON of the figures")
    a = ap.parse_args(argv)
    from jaxplan.lattice.planner import LatticePlanner
    from jaxplan.scenarios.batch import stack_scenes
    from jaxplan.scenarios.builtin import builtin_records
    from jaxplan.sim.rollout import SimConfig, driven_scene, rollout
    from jaxplan.tuning.closed_loop import drive_objective

    recs = builtin_records(quick=a.scenes <= 24, seed=0)
    kinds: dict = {}
    for r in recs:
        kinds.setdefault(r.name.rsplit("-", 1)[0], []).append(r)
    order = [r for group in zip(*kinds.values()) for r in group][:a.scenes]
    batch = jax.tree_util.tree_map(lambda x: np.asarray(x, np.float64) if np.asarray(x).dtype == np.float32 else x,
                                   stack_scenes([r.scene for r in order]))
    planner = LatticePlanner(options=(("select_temperature", a.temperature),))
    cfg = SimConfig(n_steps=a.steps, stop_at_goal=False, remat=True)
    p0 = planner.init_params()

    def objective(p):
        log = rollout(planner, batch, cfg, p)
        return jnp.mean(drive_objective(log, driven_scene(log, batch), planner.vehicle)["total"])

    t = time.perf_counter()
    val, g = jax.value_and_grad(objective)(p0)
    t_grad = time.perf_counter() - t
    rows = []
    for name in a.weights.split(","):
        w = float(getattr(p0, name))
        h = a.h * max(abs(w), 1e-3)
        up = objective(dataclasses.replace(p0, **{name: getattr(p0, name) + h}))
        down = objective(dataclasses.replace(p0, **{name: getattr(p0, name) - h}))
        fd = float(up - down) / (2 * h)
        ad = float(getattr(g, name))
        rel = abs(ad - fd) / max(abs(fd), 1e-12)
        rows.append({"weight": name, "value": w, "grad": ad, "finite_difference": fd, "relative_error": rel})
        print(f"{name:10s} grad {ad: .6e}  fd {fd: .6e}  rel.err {rel:.2e}")
    out = {"scenes": len(order), "steps": a.steps, "temperature": a.temperature, "objective": float(val),
           "grad_s": t_grad, "rows": rows, "devices": str(jax.devices()[0].platform)}
    print(json.dumps({k: v for k, v in out.items() if k != "rows"}))
    if a.out:
        with open(a.out, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
