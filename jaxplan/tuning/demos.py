"""Human demonstrations from recorded traffic (host side, numpy).

Every recorded vehicle with enough future becomes a demonstration: its state at a
start time, the centre line of the lane it drives in (following successors), the
other recorded vehicles as obstacles with their recorded futures as predictions,
and its own recorded future as the human choice. Each demonstration is moved into
its own local frame (start position at the origin, headings unchanged) and padded
to fixed sizes, so a list of them stacks into one batched pytree.
"""
from __future__ import annotations

import dataclasses
import zlib

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.scenarios.loader import Scenario, ScenarioError, lane_at, lane_polyline
from jaxplan.scenarios.polylines import arc_length, nearest_on_polyline, resample_polyline


@dataclasses.dataclass(frozen=True)
class DemoConfig:
    """Sizes of a demonstration (static).

    Attributes:
        horizon: seconds of human future kept (T = horizon / dt + 1 samples).
        stride: seconds between start times taken from one recorded vehicle.
        n_obstacles: K, the nearest other vehicles kept at the start.
        ref_points: P, samples of the reference line.
        ref_back, ref_ahead: metres of reference line behind and ahead of the start.
        min_speed: vehicles slower than this at the start are skipped (m/s).
        max_lane_offset: start farther than this from the lane centre is skipped (m).
    """

    horizon: float = 5.0
    stride: float = 2.0
    n_obstacles: int = 16
    ref_points: int = 96
    ref_back: float = 10.0
    ref_ahead: float = 180.0
    min_speed: float = 1.0
    max_lane_offset: float = 2.5


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Demo:
    """One demonstration (or a batch with leading dims), in its local frame.

    Attributes:
        ego: ``(5,)`` start state [x, y, heading, v, a] (x = y = 0).
        ref_xy: ``(P, 2)`` reference line samples (lane centre line).
        obstacles: ``(K, T, 5)`` other vehicles' boxes at the demo's times.
        obstacle_valid: ``(K, T)``.
        human_xy: ``(T, 2)`` the recorded future (index 0 = start).
        human_v: ``(T,)`` recorded speed.
        t: ``(T,)`` times from the start.
        obstacle_static: ``(K,)`` static obstacles (held beyond ``T`` by the planners); None: none.
    """

    ego: jax.Array
    ref_xy: jax.Array
    obstacles: jax.Array
    obstacle_valid: jax.Array
    human_xy: jax.Array
    human_v: jax.Array
    t: jax.Array
    obstacle_static: jax.Array = None


def is_validation(scenario_id: str, share: int = 4) -> bool:
    """Deterministic split by scenario: one scenario in ``share`` goes to validation."""
    return zlib.crc32(scenario_id.encode()) % share == 0


def scenario_demos(sc: Scenario, cfg: DemoConfig = DemoConfig()) -> list[Demo]:
    """Every demonstration of one scenario, as unbatched numpy-backed ``Demo``s."""
    boxes = np.asarray(sc.obstacles.boxes, np.float64)   # (K, S, 5)
    valid = np.asarray(sc.obstacles.valid)               # (K, S)
    static = np.asarray(sc.obstacles.static)             # (K,)
    n_t = int(round(cfg.horizon / sc.dt)) + 1
    stride = max(1, int(round(cfg.stride / sc.dt)))
    S = boxes.shape[1] if boxes.ndim == 3 else 0
    demos = []
    for i in range(boxes.shape[0]):
        for k0 in range(0, S - n_t + 1, stride):
            win = slice(k0, k0 + n_t)
            if not valid[i, win].all():
                continue
            x0, y0, _, _, th0 = boxes[i, k0]
            traj = boxes[i, win, :2]
            step = np.diff(traj, axis=0)
            v = np.concatenate([np.linalg.norm(step, axis=1) / sc.dt, [0.0]])
            v[-1] = v[-2]
            if v[0] < cfg.min_speed:
                continue
            try:
                lane = lane_at(sc, [x0, y0], th0)
                rxy = lane_polyline(sc, lane, max_length=cfg.ref_ahead + 50.0)
            except ScenarioError:
                continue
            keep = np.concatenate([[True], np.linalg.norm(np.diff(rxy, axis=0), axis=1) > 1e-3])
            rxy = rxy[keep]  # lanelets share their end points
            rs = arc_length(rxy)
            j, along, off = nearest_on_polyline(rxy, np.array([x0, y0]))
            s0 = rs[j] + along
            if off > cfg.max_lane_offset:
                continue
            origin = np.array([x0, y0])
            ref_xy = resample_polyline(rxy, rs, np.linspace(s0 - cfg.ref_back, s0 + cfg.ref_ahead, cfg.ref_points))
            others = np.array([j for j in range(boxes.shape[0]) if j != i and valid[j, k0]], int)
            K = cfg.n_obstacles
            obs = np.zeros((K, n_t, 5))
            obs[..., 2:4] = 1.0  # padding: unit boxes, never valid
            ok = np.zeros((K, n_t), bool)
            st = np.zeros(K, bool)
            if len(others):
                dist = np.linalg.norm(boxes[others, k0, :2] - origin, axis=1)
                near = others[np.argsort(dist)[:K]]
                obs[:len(near)] = boxes[near, win]
                obs[:len(near), :, :2] -= origin
                ok[:len(near)] = valid[near, win]
                st[:len(near)] = static[near]
                obs[~ok] = [0.0, 0.0, 1.0, 1.0, 0.0]
            a0 = (v[1] - v[0]) / sc.dt
            demos.append(Demo(np.array([0.0, 0.0, th0, v[0], a0]), ref_xy - origin, obs, ok,
                              traj - origin, v, np.arange(n_t) * sc.dt, st))
    return demos


def stack(demos: list[Demo]) -> Demo:
    """Stack demonstrations into one batched ``Demo`` of float32 arrays."""
    if not demos:
        raise ValueError("no demonstrations to stack")
    return jax.tree.map(lambda *xs: jnp.asarray(np.stack(xs), jnp.float32 if np.asarray(xs[0]).dtype.kind == "f"
                                                else None), *demos)


def load_demos(scenarios, cfg: DemoConfig = DemoConfig()) -> tuple[Demo | None, Demo | None, dict]:
    """Train and validation demonstrations from loaded scenarios, split by scenario id.

    Returns:
        (train, validation, info) where each is a batched ``Demo`` or None when empty,
        and info counts demonstrations per scenario.
    """
    train, val, info = [], [], {}
    for sc in scenarios:
        d = scenario_demos(sc, cfg)
        info[sc.id] = len(d)
        (val if is_validation(sc.id) else train).extend(d)
    return (stack(train) if train else None), (stack(val) if val else None), info


def synthetic_demos(n: int, seed: int = 0, cfg: DemoConfig = DemoConfig()) -> Demo:
    """``n`` demonstrations from ``jaxplan.scenarios.synthetic.road_scenes``.

    The "human" future keeps the start speed on the lane centre (replace it, for
    example with a lattice driver's choice, to generate choices with known weights).
    """
    from jaxplan.scenarios.synthetic import road_scenes

    sc = road_scenes(n, seed, cfg.n_obstacles, cfg.horizon, 0.1, cfg.ref_points, cfg.ref_back, cfg.ref_ahead)
    v = np.repeat(sc.ego[:, 3:4], sc.t.shape[1], axis=1)
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32) if np.asarray(x).dtype.kind == "f"
                                  else jnp.asarray(x), Demo(sc.ego, sc.ref_xy, sc.boxes, sc.valid, sc.cruise, v, sc.t,
                                                       sc.static))
