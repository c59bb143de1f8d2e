"""Benchmark: the jaxplan lattice against Frenetix (C++ Frenet sampler) on the same work.

Both sides sample ``N`` trajectories (end speeds x lateral offsets, quintic lateral paths
reached at the horizon, 3 s at dt = 0.1 s, 31 samples) along the same **curved** reference
line (a straight run into an arc of radius 150 m) from the same state, and run the same
stages:

- **kinematic costs only**: generation, the feasibility checks (Frenetix: acceleration,
  curvature and velocity constraints; jaxplan: the feasibility filter's curvature,
  lateral / longitudinal acceleration, jerk and reverse checks) and the cost terms
  (longitudinal and lateral jerk, distance to the reference path, velocity offset to the
  set speed; jaxplan computes all of its features, the base features and the road terms);
- **full pipeline with K moving obstacles** (default 20): the above plus the
  distance-to-obstacles cost and real collision checking of every trajectory against
  every obstacle at every step: jaxplan's exact SAT box check (with the safety buffers,
  the terminal condition and the selection) behind the road planner's broad phase
  (``near_k``: per lateral group and step the nearest obstacles by bounding circles get the
  exact test, the others their circle distance, which never exceeds the true separation:
  no collision is missed; ``--near-k 0`` checks every obstacle exactly); Frenetix's trajectories are checked with
  pycrcc (commonroad-drivability-checker), one ``TimeVariantCollisionObject`` per
  trajectory against a ``CollisionChecker`` of the obstacles' time-variant boxes; that
  check is timed separately and included.

jaxplan's headline figure times one plan call that returns what a planner uses: the choice, the
chosen trajectory and every candidate's features, costs and flags (``plan(...,
keep_candidates=False)``; inside a caller's ``jit``, such as ``jaxplan drive``'s step, XLA drops the
unread arrays by itself). Every candidate is still generated and checked at every sample; its
trajectory arrays are not written out. The call that also returns every candidate's trajectory
(the whole ``LatticeResult``) is timed beside it (``..._all_trajectories_out``).

Frenetix runs sequentially (``evaluate_all_current_functions``) and concurrently
(``evaluate_all_current_functions_concurrent``, and the pycrcc checks in a thread pool
of ``os.cpu_count()`` threads). Throughput in trajectories/s, best of ``--reps`` rounds, each
round calling jaxplan (both forms), Frenetix sequential and Frenetix concurrent ``--inner``
times each in turn, so that every side is sampled over the same stretch of time. (This
machine's speed drifts by tens of per cent between minutes: timed one side after the other,
two runs of the same code gave 14.0x and 6.9x at N = 1764. With one call per round, jaxplan's
sub-millisecond call always ran just after Frenetix's and lost a third to a half of its
speed.) The ratios are from this one run; jaxplan's compile time is reported
separately. The load average is recorded; compare ratios. ``--batch B`` adds rows ``*_batchB``: one
``plan_batch`` call of B plans (start speeds spread over V0 +- 2 m/s, the same road and obstacles)
against Frenetix planning the same B plans one after the other (sequential / concurrent evaluation).

Frenetix 0.4.0 needs Python < 3.13 and its own commonroad pins: run this with a venv that
has ``frenetix==0.4.0``, ``commonroad-drivability-checker`` and jax (e.g.
``/work/venvs/lattice-bench/bin/python``, with the repository on ``PYTHONPATH``)::

    python experiments/bench_lattice.py [--sizes 1000 5000] [--obstacles 20] [--batch 8] [--out results/bench_lattice.json]
"""
from __future__ import annotations

import argparse
import concurrent.futures
import itertools
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.cli_args import nonnegative_int, positive_int
from jaxplan.eval.timing import best_times_interleaved, write_figures
from jaxplan.geometry import ReferenceLine
from jaxplan.lattice import CostWeights, LatticeConfig, PlanState
from jaxplan.lattice.plan import _plan_batch_jit, plan_kernel
from jaxplan.types import Obstacles, VehicleParams

HORIZON, DT, V0 = 3.0, 0.1, 15.0
CAR = VehicleParams(length=4.508, width=1.61, wheelbase=2.578, rear_overhang=0.8313, max_steer=0.55)
RADIUS = 150.0


def reference(n=600):
    """A straight 60 m into an arc of radius ``RADIUS`` (``(n, 2)``), starting 20 m behind the car."""
    s = np.linspace(0.0, 420.0, n)
    x = np.where(s < 80, s - 20, 60 + RADIUS * np.sin((s - 80) / RADIUS))
    y = np.where(s < 80, 0.0, RADIUS * (1 - np.cos((s - 80) / RADIUS)))
    return np.stack([x, y], 1)


def _grid(n):
    """End speeds x offsets with about n candidates: (V, L)."""
    v = max(2, int(round(np.sqrt(n / 5))))
    return v, max(1, n // v)


def _obstacles(k, t, ref):
    """k cars on three lanes ahead along the reference line at 8 m/s: boxes (k, T, 5)."""
    from jaxplan.geometry.frenet import frenet_to_cartesian_state

    rl = ReferenceLine.from_polyline(ref)
    i = np.arange(k)
    s = 20 + 25 + 6 * i[:, None] + 8 * t[None]
    l = np.broadcast_to((((i % 3) - 1) * 3.5)[:, None], s.shape)
    xy, th, _ = frenet_to_cartesian_state(rl, jnp.asarray(s), jnp.asarray(l), 0 * s, 0 * s)
    xy, th = np.asarray(xy), np.asarray(th)
    return np.concatenate([xy, np.full(s.shape + (1,), 4.5), np.full(s.shape + (1,), 1.8), th[..., None]], -1)


NEAR_K = LatticeConfig.road().near_k  # the road planner's broad phase (0: the dense check)


def lattice_config(n, near_k=None):
    V, L = _grid(n)
    return LatticeConfig(horizon=HORIZON, dt=DT, speed_deltas_kmh=tuple(np.linspace(-36, 36, V).round(4)),
                         escalation=(1.0,), n_offsets=L, offset_span=3.0, vehicle=CAR, buffer_lon=1.0,
                         buffer_lat=0.3, terminal=True, near_budget=0.0,
                         near_k=NEAR_K if near_k is None else near_k)


def start_speeds(batch):
    """The start speeds of a batch of ``batch`` plans (m/s): ``V0`` alone, or spread over ``V0 +- 2``."""
    return np.array([V0]) if batch == 1 else V0 + np.linspace(-2.0, 2.0, batch)


def jaxplan_call(n, k, near_k=None, keep_candidates=False, batch=1):
    """``(call, compile s, candidates, collided, feasible)``: ``call()`` runs one plan and blocks
    (``batch > 1``: one ``plan_batch`` call of ``batch`` plans from ``start_speeds(batch)``, on the
    same road and obstacles; candidates, collided and feasible are then summed over the batch).

    ``keep_candidates=False`` (the headline): the call returns the choice, the chosen trajectory and
    every candidate's features, costs and flags, as a planner uses it (``plan(...,
    keep_candidates=False)``; inside a caller's jit the same by dead-code elimination): every
    candidate is still generated and checked at every sample, but its trajectory arrays are not
    written out. ``True``: the whole ``LatticeResult`` with every candidate's trajectory."""
    cfg = lattice_config(n, near_k)
    ref_xy = reference()
    ref = ReferenceLine.from_polyline(ref_xy)
    t = np.arange(cfg.n_steps) * DT
    obs = Obstacles(jnp.asarray(_obstacles(k, t, ref_xy), jnp.float32), jnp.ones((k, len(t)), bool),
                    jnp.asarray(t, jnp.float32)) if k else Obstacles.empty(jnp.asarray(t, jnp.float32))
    w = jax.tree_util.tree_map(jnp.asarray, CostWeights())  # on the device once, as a caller's weights are
    if batch == 1:
        st = PlanState.make(0.0, 0.0, 0.0, V0, v_set=V0)
        run = lambda: jax.block_until_ready(plan_kernel(st, ref, obs, cfg, w, None, keep_candidates))
    else:
        v = start_speeds(batch)
        st = PlanState.make(0 * v, 0 * v, 0 * v, v, a=0 * v, kappa=0 * v, v_set=0 * v + V0, d_crossroad=0 * v + np.inf)
        many = lambda tree: jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (batch,) + a.shape), tree)
        ref, obs = many(ref), many(obs)
        run = lambda: jax.block_until_ready(_plan_batch_jit(st, ref, obs, cfg, w, None, keep_candidates))
    t0 = time.perf_counter()
    res = run()
    compile_s = time.perf_counter() - t0
    return (run, compile_s, cfg.n_candidates * batch, int(np.asarray(res.collided).sum()),
            int(np.asarray(res.feasible).sum()))


def _pycrcc_obstacles(boxes):
    import commonroad_dc.pycrcc as pycrcc

    cc = pycrcc.CollisionChecker()
    for b in boxes:
        tvo = pycrcc.TimeVariantCollisionObject(0)
        for x, y, L, W, th in b:
            tvo.append_obstacle(pycrcc.RectOBB(0.5 * L, 0.5 * W, th, x, y))
        cc.add_collision_object(tvo)
    return cc


def _pycrcc_check(cc, trajs):
    """Collision flags of Frenetix trajectories (the car's box at each step) against ``cc``."""
    import commonroad_dc.pycrcc as pycrcc

    off = 0.5 * CAR.length - CAR.rear_overhang
    out = []
    for tr in trajs:
        c = tr.cartesian
        x, y, th = np.asarray(c.x), np.asarray(c.y), np.asarray(c.theta)
        tvo = pycrcc.TimeVariantCollisionObject(0)
        for xi, yi, ti in zip(x + off * np.cos(th), y + off * np.sin(th), th):
            tvo.append_obstacle(pycrcc.RectOBB(0.5 * CAR.length, 0.5 * CAR.width, ti, xi, yi))
        out.append(cc.collide(tvo))
    return out


def frenetix_calls(n, k, threads, batch=1):
    """``(sequential call, concurrent call, trajectories, collided, pycrcc share, close)``: each call
    runs the whole Frenetix side once (``batch > 1``: the ``batch`` plans of ``start_speeds(batch)``
    one after the other; trajectories and collided summed over them); ``pycrcc share()`` is the
    share of the best sequential call's time spent in the pycrcc check; ``close()`` ends the thread
    pool."""
    import frenetix
    import frenetix.trajectory_functions as tf
    import frenetix.trajectory_functions.cost_functions as cf
    import frenetix.trajectory_functions.feasability_functions as ff

    ref = reference()
    cs = frenetix.CoordinateSystemWrapper(ref)
    h = frenetix.TrajectoryHandler(dt=DT)
    h.add_function(tf.FillCoordinates(lowVelocityMode=False, initialOrientation=0.0, coordinateSystem=cs,
                                      horizon=int(HORIZON)))
    h.add_feasability_function(ff.CheckAccelerationConstraint(switchingVelocity=4.86, maxAcceleration=8.0,
                                                              wholeTrajectory=False))
    h.add_feasability_function(ff.CheckCurvatureConstraint(deltaMax=float(CAR.max_steer), wheelbase=float(CAR.wheelbase),
                                                           wholeTrajectory=False))
    h.add_feasability_function(ff.CheckVelocityConstraint(wholeTrajectory=False))
    for c in (cf.CalculateLongitudinalJerkCost("longitudinal_jerk", 1.0), cf.CalculateLateralJerkCost("lateral_jerk", 1.0),
              cf.CalculateDistanceToReferencePathCost("distance_to_reference_path", 1.0),
              cf.CalculateVelocityOffsetCost("velocity_offset", 1.0, V0, DT, 0.0, False, 2)):
        h.add_cost_function(c)
    t = np.arange(int(round(HORIZON / DT)) + 1) * DT
    boxes = _obstacles(k, t, ref) if k else None
    if k:
        h.add_cost_function(cf.CalculateDistanceToObstacleCost("distance_to_obstacles", 1.0,
                                                               np.ascontiguousarray(boxes[:, 0, :2], float)))
        cc = _pycrcc_obstacles(boxes)
    V, L = _grid(n)
    Ms = [np.array(list(itertools.product([0.0], [HORIZON], [20.0], [v0], [0.0], V0 + np.linspace(-10, 10, V), [0.0],
                                          [0.0], [0.0], [0.0], np.linspace(-3, 3, L), [0.0], [0.0])))
          for v0 in start_speeds(batch)]
    pool = concurrent.futures.ThreadPoolExecutor(threads)
    seq_calls = []  # (whole call, collision check) seconds of each sequential call

    def plan(M, concurrent_eval):
        """One plan: ``(collision flags or None, seconds in pycrcc)``."""
        h.reset_Trajectories()
        h.generate_trajectories(M, False)
        if concurrent_eval:
            h.evaluate_all_current_functions_concurrent(True)
        else:
            h.evaluate_all_current_functions(True)
        if not k:
            return None, 0.0
        trajs = list(h.get_sorted_trajectories())
        t0 = time.perf_counter()
        if concurrent_eval:
            parts = [trajs[i::threads] for i in range(threads)]
            flags = sum(pool.map(lambda p: _pycrcc_check(cc, p), parts), [])
        else:
            flags = _pycrcc_check(cc, trajs)
        return flags, time.perf_counter() - t0

    def run(concurrent_eval):
        t_call = time.perf_counter()
        out = [plan(M, concurrent_eval) for M in Ms]
        if not concurrent_eval:
            seq_calls.append((time.perf_counter() - t_call, sum(c for _, c in out)))
        return None if not k else sum((f for f, _ in out), [])

    flags = run(False)
    run(True)
    seq_calls.clear()

    def share():
        total, check = min(seq_calls)  # the best sequential call: the share of its time spent in pycrcc
        return check / total

    return (lambda: run(False)), (lambda: run(True)), sum(map(len, Ms)), int(np.sum(flags)) if flags is not None else 0, share, \
        pool.shutdown


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=positive_int, nargs="+", default=[1000, 5000])
    ap.add_argument("--obstacles", type=nonnegative_int, default=20)
    ap.add_argument("--reps", type=positive_int, default=10,
                    help="best of this many rounds; each round calls every side --inner times, in turn")
    ap.add_argument("--inner", type=positive_int, default=5,
                    help="calls of each side per round (the first after the other side's work runs cold)")
    ap.add_argument("--near-k", type=nonnegative_int, default=NEAR_K,
                    help=f"jaxplan's collision broad phase: obstacles checked exactly per lateral group and step "
                         f"(default {NEAR_K}, the road planner's; 0: every obstacle)")
    ap.add_argument("--batch", type=positive_int, default=1,
                    help="also time batches of this many plans (start speeds spread over V0 +- 2 m/s): one "
                         "plan_batch call against Frenetix planning them one after the other (rows *_batchB)")
    ap.add_argument("--out", default="results/bench_lattice.json")
    args = ap.parse_args(argv)
    threads = os.cpu_count() or 1
    res = {"device": str(jax.devices()[0]), "cpu_count": threads, "machine": platform.machine(),
           "load_average_1min_start": os.getloadavg()[0], "samples_per_trajectory": int(round(HORIZON / DT)) + 1,
           "obstacles": args.obstacles, "reference": f"straight 60 m + arc R={RADIUS:g} m", "jaxplan_near_k": args.near_k}
    try:
        import frenetix  # noqa: F401
        import commonroad_dc.pycrcc  # noqa: F401
        have_fx = True
        from importlib.metadata import version

        res["frenetix_version"] = version("frenetix")
    except ImportError:
        have_fx = False
        print("frenetix / commonroad-drivability-checker not installed: Frenetix skipped "
              "(pip install frenetix==0.4.0 commonroad-drivability-checker)")
    for n, batch in itertools.product(args.sizes, sorted({1, args.batch})):
        for k, kind in ((0, "kinematic"), (args.obstacles, f"obstacles{args.obstacles}")):
            tag = kind if batch == 1 else f"{kind}_batch{batch}"
            run, comp, n_c, n_col, n_feas = jaxplan_call(n, k, args.near_k, batch=batch)
            calls = {"jaxplan": run}
            if batch == 1:
                calls["jaxplan_all"] = jaxplan_call(n, k, args.near_k, True)[0]
            res[f"jaxplan_{tag}_N{n}_compile_s"] = comp
            res[f"jaxplan_{tag}_N{n}_candidates"] = n_c
            res[f"jaxplan_{tag}_N{n}_feasible"] = n_feas
            if k:
                res[f"jaxplan_{tag}_N{n}_collided"] = n_col
            if have_fx:
                seq_call, con_call, n_f, fx_col, cc_share, close = frenetix_calls(n, k, threads, batch)
                calls.update(frenetix_seq=seq_call, frenetix_con=con_call)
            best = best_times_interleaved(calls, args.reps, args.inner)  # every side in each round
            rate = n_c / best["jaxplan"]
            res[f"jaxplan_{tag}_N{n}_traj_per_s"] = rate
            if batch == 1:
                res[f"jaxplan_{tag}_N{n}_traj_per_s_all_trajectories_out"] = n_c / best["jaxplan_all"]
            if have_fx:
                seq, con = n_f / best["frenetix_seq"], n_f / best["frenetix_con"]
                close()
                res[f"frenetix_{tag}_N{n}_sequential_traj_per_s"] = seq
                res[f"frenetix_{tag}_N{n}_concurrent_traj_per_s"] = con
                res[f"frenetix_{tag}_N{n}_trajectories"] = n_f
                if k:
                    res[f"frenetix_{tag}_N{n}_collided_pycrcc"] = fx_col
                    res[f"frenetix_{tag}_N{n}_pycrcc_share_of_time"] = cc_share()
                res[f"ratio_{tag}_N{n}_vs_sequential"] = rate / seq
                res[f"ratio_{tag}_N{n}_vs_concurrent"] = rate / con
    res["load_average_1min_end"] = os.getloadavg()[0]
    write_figures(res, args.out)
    return res


if __name__ == "__main__":
    main()
