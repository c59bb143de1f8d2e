"""Planner callback around the park-out planner (``jaxplan.parking.plan_parkout``).

The supervisor asks for a plan from the car's current pose; this adapter renders
the occupancy grid of the perceived obstacle boxes (once, in the scene's frame,
read from the current pose), asks the park-out planner for one move, drives it
virtually to its end and repeats
(``lax.scan`` over ``config.max_moves``) until the car is out or stuck. The
moves are joined into one plan whose move ends are gear-shift points, so the
supervisor's intermediate destinations are the park-out planner's own re-plan
points. Poses are in the scene's initial frame (the parked car's start pose is
the origin), as the park-out planner expects.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.geometry import box_corners
from jaxplan.parking.config import ParkoutConfig
from jaxplan.parking.parkout import plan_parkout
from jaxplan.parking.render import render_grid
from jaxplan.parking.scenes import ParkingScene
from jaxplan.replan.longitudinal import MotionLimits
from jaxplan.replan.planner import Plan, PlanRequest, finish_plan
from jaxplan.types import VehicleParams


@dataclasses.dataclass(frozen=True)
class ParkoutPlanner:
    """``PlanRequest -> Plan`` with ``config.max_moves * config.steps`` points (static, hashable).

    Drive it with a supervisor whose ``limits`` are ``limits`` and whose ``clearance`` is at
    most ``clearance`` (``ManeuverSimConfig`` checks both): a park-out move ends where the
    footprint grown by the planner's margin would touch the grid, so it passes the parked
    cars closer than the supervisor's default clearance, and a supervisor that grows the car
    by more rejects every plan (the car never starts).
    """

    config: ParkoutConfig = ParkoutConfig(max_moves=8)  # the plan size the replanning figures were made with
    vehicle: VehicleParams = VehicleParams()
    limits: MotionLimits = MotionLimits(v_fwd=1.0, v_rev=1.0, accel=0.5, decel=1.0)

    @property
    def clearance(self) -> float:
        """Least distance (m) the plans keep from the obstacle boxes they were planned around:
        the smallest margin the planner may use (``min_margin`` with ``shrink_margin``, else
        ``margin``) less the grid's error, half a cell diagonal (``ParkoutConfig.min_margin``)."""
        cfg = self.config
        m = cfg.min_margin if cfg.shrink_margin else cfg.margin
        return max(0.0, float(m) - 0.5 * math.sqrt(2.0) * float(cfg.cell))

    def __call__(self, r: PlanRequest) -> Plan:
        cfg, veh = self.config, self.vehicle
        dtype = r.obstacles.dtype
        z = jnp.zeros((), dtype)
        scene = ParkingScene(
            polygons=box_corners(r.obstacles),
            valid=r.obstacles_valid,
            start=jnp.asarray(r.start, dtype),
            edge_noise=z,
            salt=z,
            occlusion=jnp.zeros((), bool),
            sensor_range=z + jnp.inf,
            unknown_patches=z,
        )
        grid = render_grid(scene, jnp.zeros(3, dtype), jnp.zeros((2,), jnp.uint32), cfg, veh, sensors=False)

        def move(carry, _):
            pose, done, out = carry
            p = plan_parkout(pose, grid, cfg, veh)
            tr = p.trajectory
            go = ~done & (tr.length >= cfg.min_progress)
            return (
                (jnp.where(go, tr.end_pose, pose), done | ~go | p.out, out | (go & p.out)),
                (tr.poses, tr.gear, tr.valid & go),
            )

        f = jnp.zeros((), bool)
        (_, _, out), (poses, gear, valid) = jax.lax.scan(
            move, (jnp.asarray(r.start, dtype), f, f), None, length=cfg.max_moves
        )
        poses, gear, valid = poses.reshape(-1, 3), gear.reshape(-1).astype(jnp.int32), valid.reshape(-1)
        order = jnp.argsort(~valid, stable=True)  # driven points first, in order
        poses, gear, valid = poses[order], gear[order], valid[order]
        ok = jnp.any(valid)
        valid = valid.at[0].set(True)
        last = jnp.maximum(jnp.sum(valid) - 1, 0)
        poses = jnp.where(valid[:, None], poses, poses[last])
        poses = jnp.where(ok, poses, jnp.asarray(r.start, dtype))
        gear = jnp.where(valid, gear, gear[last])
        # ``ok``: the joined moves end fully out (else the car stops at the end and re-plans).
        return finish_plan(poses[:, :2], poses[:, 2], gear, valid, jnp.abs(r.speed), self.limits, ok & out)


def parkout_scenarios(seed: int, n: int, planner: ParkoutPlanner = ParkoutPlanner(), phantom: bool = True, **scene_kw):
    """``n`` park-out runs for the closed loop (host side): ``jaxplan.parking.make_scenes``
    slots, the parked cars and clutter as real obstacles, and (``phantom``) a false
    positive on the nominal way out that shows for 0.6 s when the car comes within 3 m.
    The goal is the end pose of the nominal park-out (the adapter ignores the goal; the
    simulator's success then means "ended where the undisturbed park-out ends").

    Returns:
        (``ManeuverScenario`` batch, nominal ``Plan`` batch).
    """
    import numpy as np

    from jaxplan.parking.scenes import make_scenes
    from jaxplan.replan.simulator import ManeuverScenario, _jit_planner

    rng = np.random.default_rng(seed)
    kw: dict[str, Any] = dict(front_gap=rng.uniform(0.7, 1.2, n), rear_gap=rng.uniform(0.7, 1.2, n))
    kw.update(scene_kw)
    scene, info = make_scenes(rng, n, planner.vehicle, **kw)
    boxes = jnp.asarray(info["boxes"], jnp.float32)
    valid = jnp.asarray(scene.valid)
    z3 = jnp.zeros((n, 3))
    # The request as the supervisor makes it: the perceived slots are the real boxes, then the
    # phantom and the pedestrian of the scenario (not seen here), so that the nominal park-outs
    # are planned by the program the host loop calls (``simulate_host``), compiled once.
    k = boxes.shape[1] + 2
    req = PlanRequest(
        z3,
        jnp.zeros(n),
        jnp.ones(n, jnp.int32),
        jnp.ones(n, jnp.int32),
        z3,
        jnp.zeros((n, k, 5)).at[:, : boxes.shape[1]].set(boxes),
        jnp.zeros((n, k, 2)),
        jnp.zeros((n, k), bool).at[:, : boxes.shape[1]].set(valid),
        jnp.zeros(n, bool),
        z3,
        z3,
    )
    plan_one = _jit_planner(planner)
    nominal = jax.tree.map(lambda *a: jnp.stack(a), *[plan_one(jax.tree.map(lambda a: a[i], req)) for i in range(n)])
    last = jnp.sum(nominal.valid, -1) - 1
    take = lambda a: jnp.take_along_axis(a, last[:, None], -1)[:, 0]  # noqa: E731
    goal = jnp.stack([take(nominal.traj.x), take(nominal.traj.y), take(nominal.traj.theta)], -1)
    # The phantom sits on the nominal path two thirds of the way along it.
    j = (2 * last) // 3
    pick = lambda a: jnp.take_along_axis(a, j[:, None], -1)[:, 0]  # noqa: E731
    ph = jnp.stack(
        [
            pick(nominal.traj.x) + 2.0 * jnp.cos(pick(nominal.traj.theta)),
            pick(nominal.traj.y) + 2.0 * jnp.sin(pick(nominal.traj.theta)),
            jnp.full(n, 0.6),
            jnp.full(n, 0.6),
            jnp.zeros(n),
        ],
        -1,
    )[:, None]
    keys = jax.random.split(jax.random.PRNGKey(seed), n)
    sc = ManeuverScenario(
        start=z3,
        goal=goal,
        park=jnp.zeros(n, bool),
        goal_bias=z3,
        goal_sigma=jnp.zeros(n),
        yaw_sigma=jnp.zeros(n),
        real=boxes,
        real_valid=valid,
        phantom=ph,
        phantom_valid=jnp.full((n, 1), phantom),
        phantom_range=jnp.full((n, 1), 3.0),
        phantom_dur=jnp.full((n, 1), 0.6),
        dyn_point=jnp.zeros((n, 1, 2)),
        dyn_dir=jnp.tile(jnp.array([[[1.0, 0.0]]]), (n, 1, 1)),
        dyn_speed=jnp.ones((n, 1)),
        dyn_size=jnp.ones((n, 1, 2)),
        dyn_range=jnp.zeros((n, 1)),
        dyn_valid=jnp.zeros((n, 1), bool),
        key=jnp.asarray(keys),
    )
    return sc, nominal
