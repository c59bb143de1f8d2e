"""The built-in synthetic road scenes: survivable by construction.

Each scene is a scenario object of the shared JSON format (``../shared/data/README.md``), so
it loads through the same ``parse_scenario`` / ``build_scene`` path as recorded traffic and
can be written to files for other planners (``jaxplan scenes --out DIR``). A straight or
curved road of two or three same-direction lanes (3.5 m) is one long lanelet per lane;
the car starts in a lane at 8-20 m/s; the goal is a rectangle across the road 90-150 m
ahead, with a time window that a car keeping about half its start speed meets.

Kinds (``KINDS``): ``stopped_car`` (a stopped car in the ego lane), ``slow_leader``,
``cut_in`` (a slower car from the next lane cuts in ahead), ``parked_cars`` (parked cars
on the road's right edge reaching into the ego lane), ``curve_stop`` (a stopped car on a
curve of radius 80-200 m) and ``dense_next_lane`` (a stopped car ahead, a faster platoon
in the next lane).

A generated scene is kept only if plain in-lane braking at ``-5 m/s^2`` from ``t = 0``
(the ``brake`` planner) avoids every obstacle, checked with the simulator and the
geometry core's overlap metric; so a collision in a built-in scene is always the
planner's fault.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

KINDS = ("stopped_car", "slow_leader", "cut_in", "parked_cars", "curve_stop", "dense_next_lane")
LANE = 3.5
ROAD_LENGTH = 450.0
START_S = 30.0
DT = 0.1
RECORD_STEPS = 251  # 25 s of obstacle trajectories
SURVIVAL_DECEL = 5.0


class SyntheticRoad:
    """A straight road (curvature 0) or an arc, parametrised by arc length ``s`` of its
    centre reference (the right edge of lane 0 is at ``l = -LANE / 2``)."""

    def __init__(self, kappa: float, heading: float):
        self.kappa, self.h0 = kappa, heading

    def pose(self, s, l):
        s, l = np.asarray(s, float), np.asarray(l, float)
        th = self.h0 + self.kappa * s
        if abs(self.kappa) < 1e-9:
            x, y = s * math.cos(self.h0), s * math.sin(self.h0)
        else:
            x = (np.sin(th) - math.sin(self.h0)) / self.kappa
            y = (math.cos(self.h0) - np.cos(th)) / self.kappa
        return np.stack([x - l * np.sin(th), y + l * np.cos(th)], -1), th


def road_lanelets(road: SyntheticRoad, n_lanes: int, limit: float) -> list:
    length = ROAD_LENGTH if abs(road.kappa) < 1e-9 else min(ROAD_LENGTH, 0.95 * math.pi / abs(road.kappa))
    s = np.arange(0.0, length + 1e-6, 2.0)  # a curve turns by less than 180 degrees
    out = []
    for i in range(n_lanes):
        left, _ = road.pose(s, (i + 0.5) * LANE)
        right, _ = road.pose(s, (i - 0.5) * LANE)
        d = {
            "id": 100 + i,
            "left": left.round(4).tolist(),
            "right": right.round(4).tolist(),
            "predecessors": [],
            "successors": [],
            "speed_limit": limit,
        }
        if i + 1 < n_lanes:
            d["adjacentLeft"] = {"ref": 101 + i, "drivingDir": "same"}
        if i > 0:
            d["adjacentRight"] = {"ref": 99 + i, "drivingDir": "same"}
        out.append(d)
    return out


def road_obstacle(oid, road, s, l, length=4.6, width=1.8, role="dynamic", kind="car"):
    """An obstacle following stations ``s (T,)`` and offsets ``l (T,)`` (one pair: static)."""
    s, l = np.atleast_1d(s).astype(float), np.atleast_1d(l).astype(float)
    xy, th = road.pose(s, l)
    if len(s) > 1:  # heading of the motion (the lane's, plus the lateral drift)
        ds = np.gradient(s)
        dl = np.gradient(l)
        th = th + np.arctan2(dl, np.maximum(np.abs(ds), 1e-3))
    v = np.concatenate([[0.0], np.linalg.norm(np.diff(xy, axis=0), axis=1) / DT]) if len(s) > 1 else np.zeros(1)
    if len(s) > 1:
        v[0] = v[1]
    states = [
        [round(k * DT, 4), float(xy[k, 0]), float(xy[k, 1]), float(th[k]), float(v[k]), 0.0] for k in range(len(s))
    ]
    return {"id": int(oid), "role": role, "type": kind, "length": length, "width": width, "states": states}


def scene_dict(kind: str, rng: np.random.Generator, index: int) -> dict:
    """One candidate scene of ``kind`` (not yet checked for survivability)."""
    if kind not in KINDS:
        raise ValueError(f"unknown built-in scene kind {kind!r}; known: {', '.join(KINDS)}")
    curved = kind == "curve_stop" or (kind != "parked_cars" and rng.random() < 0.3)
    radius = rng.uniform(80.0, 200.0) if kind == "curve_stop" else rng.uniform(250.0, 600.0)
    kappa = (rng.choice([-1.0, 1.0]) / radius) if curved else 0.0
    road = SyntheticRoad(kappa, rng.uniform(-math.pi, math.pi))
    n_lanes = 3 if kind in ("dense_next_lane", "cut_in") else int(rng.integers(2, 4))
    ego_lane = (
        0
        if kind == "parked_cars"
        else int(rng.integers(0, n_lanes - 1))
        if kind == "dense_next_lane"
        else int(rng.integers(0, n_lanes))
    )
    v0 = rng.uniform(8.0, 20.0) if kind != "curve_stop" else rng.uniform(8.0, min(20.0, math.sqrt(3.0 * radius)))
    limit = float(np.ceil(max(v0 + rng.uniform(0.0, 5.0), 13.9)))
    t = np.arange(RECORD_STEPS) * DT
    l_ego = ego_lane * LANE
    brake_dist = v0**2 / (2 * SURVIVAL_DECEL)
    obstacles, oid = [], 1
    if kind in ("stopped_car", "curve_stop", "dense_next_lane"):
        gap = brake_dist + rng.uniform(6.0, 30.0)
        obstacles.append(road_obstacle(oid, road, START_S + 2.3 + gap + 2.3, l_ego, role="static"))
        oid += 1
    if kind == "slow_leader":
        v_l = rng.uniform(0.0, 0.5 * v0)
        gap = rng.uniform(15.0, 45.0)
        obstacles.append(road_obstacle(oid, road, START_S + gap + 4.6 + v_l * t, np.full_like(t, l_ego)))
        oid += 1
    if kind == "cut_in":
        side = 1 if ego_lane == 0 else -1 if ego_lane == n_lanes - 1 else int(rng.choice([-1, 1]))
        v_c = v0 - rng.uniform(2.0, 6.0)
        s0 = START_S + rng.uniform(10.0, 25.0)
        t_in, dur = rng.uniform(0.5, 2.0), rng.uniform(1.5, 3.0)
        u = np.clip((t - t_in) / dur, 0.0, 1.0)
        l = l_ego + side * LANE * (1.0 - (3 * u**2 - 2 * u**3))
        obstacles.append(road_obstacle(oid, road, s0 + v_c * t, l))
        oid += 1
    if kind == "parked_cars":
        s = START_S + rng.uniform(25.0, 45.0)
        for _ in range(int(rng.integers(2, 5))):
            into = rng.uniform(0.3, 1.0)  # metres into the ego lane
            width = 1.8
            l = l_ego - 0.5 * LANE - 0.5 * width + into
            obstacles.append(road_obstacle(oid, road, s, l, width=width, role="static", kind="parkedVehicle"))
            oid += 1
            s += rng.uniform(6.0, 14.0)
    if kind == "dense_next_lane":
        v_p = v0 + rng.uniform(0.0, 5.0)
        s = START_S + rng.uniform(-40.0, 0.0)
        for _ in range(int(rng.integers(4, 8))):
            obstacles.append(road_obstacle(oid, road, s + v_p * t, np.full_like(t, l_ego + LANE)))
            oid += 1
            s += rng.uniform(9.0, 16.0)
    if kind in ("stopped_car", "slow_leader") and n_lanes > 1 and rng.random() < 0.5:
        other = (ego_lane + 1) % n_lanes
        obstacles.append(
            road_obstacle(
                oid,
                road,
                START_S + rng.uniform(-30.0, 40.0) + (v0 + rng.uniform(-2, 3)) * t,
                np.full_like(t, other * LANE),
            )
        )
    # the ego starts on its lane's centre; coordinates are made relative to it by the loader
    start, th0 = road.pose(START_S, l_ego)
    goal_d = rng.uniform(90.0, 150.0)
    mid = 0.5 * (n_lanes - 1) * LANE
    gc, gth = road.pose(START_S + goal_d + 15.0, mid)
    t_goal = goal_d / (0.5 * v0) + 4.0
    return {
        "id": f"JAXPLAN_{kind}-{index}",
        "source": "jaxplan.scenarios.builtin",
        "tags": ["synthetic", kind],
        "dt": DT,
        "lanelets": road_lanelets(road, n_lanes, limit),
        "obstacles": obstacles,
        "planning_problems": [
            {
                "id": 1,
                "initial_state": {
                    "t": 0.0,
                    "position": start.tolist(),
                    "orientation": float(th0),
                    "velocity": float(v0),
                    "acceleration": 0.0,
                },
                "goals": [
                    {
                        "rectangle": {
                            "center": gc.tolist(),
                            "length": 30.0,
                            "width": n_lanes * LANE,
                            "orientation": float(gth),
                        },
                        "time": [0.0, round(float(t_goal), 1)],
                    }
                ],
            }
        ],
    }


def survivable(records) -> np.ndarray:
    """``(n,)`` bool: in-lane braking at ``SURVIVAL_DECEL`` from ``t = 0`` touches no obstacle
    (driven to the end of each goal's time window, at most 20 s)."""
    from jaxplan.baselines import BrakePlanner
    from jaxplan.scenarios.batch import stack_scenes
    from jaxplan.sim.drive import n_steps_for, run_planner
    from jaxplan.sim.rollout import SimConfig

    planner = BrakePlanner(decel=SURVIVAL_DECEL)
    cfg = SimConfig(n_steps=n_steps_for(records, DT, 200), stop_at_goal=False)
    batch = stack_scenes([r.scene for r in records], min_steps=cfg.n_steps + 1)
    _, metrics, _ = run_planner(planner, batch, cfg)
    return ~np.asarray(metrics["overlap.collided"])


def _draw(kind: str, rng, i: int):
    """``(scenario dict, SceneRecord)`` of one scene of ``kind`` drawn from ``rng`` (``scene_dict``)."""
    from jaxplan.scenarios.build import build_scene
    from jaxplan.scenarios.loader import parse_scenario
    from jaxplan.scenarios.scene import SceneRecord

    d = scene_dict(kind, rng, i)
    sc = parse_scenario(d, d["id"])
    scene, route = build_scene(sc)
    return d, SceneRecord(d["id"], scene, sc, route)


def _generate(n_per_kind: int, seed: int, kinds=KINDS) -> list:
    """``[(scenario object, SceneRecord)]``: ``n_per_kind`` survivable scenes of each kind."""
    rng = np.random.default_rng(seed)
    kept: dict[str, list[tuple[dict, Any]]] = {k: [] for k in kinds}  # (scenario object, SceneRecord)
    for _attempt in range(10):
        cand = []
        for k in kinds:
            need = n_per_kind - len(kept[k])
            for _ in range(2 * need if need else 0):
                cand.append((k, *_draw(k, rng, 0)))
        if not cand:
            break
        ok = survivable([r for _, _, r in cand])
        for (k, d, r), good in zip(cand, ok):
            if good and len(kept[k]) < n_per_kind:
                kept[k].append((d, r))
    out = []
    for k in kinds:
        if len(kept[k]) < n_per_kind:
            raise RuntimeError(f"built-in scenes: only {len(kept[k])} survivable {k} scenes in 10 attempts")
        for i, (d, r) in enumerate(kept[k]):
            name = f"JAXPLAN_{k}-{i}"
            d = dict(d, id=name)
            sc = r.scenario.__class__(**{**r.scenario.__dict__, "id": name})
            out.append((d, r.__class__(name, r.scene, sc, r.route, "")))
    return out


def builtin_dicts(n_per_kind: int = 8, seed: int = 0, kinds=KINDS) -> list:
    """``n_per_kind`` survivable scenes of each kind, as shared-JSON scenario objects
    (deterministic in ``seed``; candidates that braking cannot survive are dropped and
    replaced by new draws)."""
    return [d for d, _ in _generate(n_per_kind, seed, kinds)]


def builtin_records(quick: bool = False, seed: int = 0) -> list:
    """``SceneRecord``s of the built-in scenes (4 per kind with ``quick``, else 16)."""
    return [r for _, r in _generate(4 if quick else 16, seed)]


def builtin_scenes(n_per_kind: int = 1, seed: int = 0, kinds=KINDS, check: bool = True) -> list:
    """``n_per_kind`` built-in scenes of each of ``kinds``, as unbatched numpy ``Scene``s (give them
    to ``jaxplan.scenarios.batch.stack_scenes`` for a batch); deterministic in ``seed``.

    Args:
        check: keep only scenes that braking survives, as ``builtin_records`` (and ``jaxplan drive
            --builtin``) do: this drives the ``brake`` planner over the candidates once (a compile
            of some seconds). False: the first ``n_per_kind`` draws of each kind, unchecked (other
            scenes than the checked ones of the same seed; a collision in them may be unavoidable).
    """
    if not check:
        rng = np.random.default_rng(seed)
        return [_draw(k, rng, i)[1].scene for k in kinds for i in range(n_per_kind)]
    return [r.scene for _, r in _generate(n_per_kind, seed, kinds)]


def write_builtin(out: str, n_per_kind: int = 16, seed: int = 0) -> list:
    """Write the built-in scenes as shared-JSON files ``out/<id>.json``; returns the paths."""
    import json
    import os

    os.makedirs(out, exist_ok=True)
    paths = []
    for d in builtin_dicts(n_per_kind, seed):
        p = os.path.join(out, f"{d['id']}.json")
        with open(p + ".tmp", "w") as f:
            json.dump(d, f)
        os.replace(p + ".tmp", p)
        paths.append(p)
    return paths
