"""Park-out scene files (JSON): reading with a clear error for every malformed field, and the result file.

Format (see the README)::

    {"vehicle": {"length": 4.8, "width": 1.9, "wheelbase": 2.9, "rear_overhang": 0.95, "max_steer": 0.55},
     "start": {"x": 12.0, "y": 3.4, "heading": 0.02},
     "road_heading": 0.0,
     "side": "left",
     "obstacles": [{"polygon": [[x, y], [x, y], [x, y], ...]}, ...]}

Lengths in metres, angles in radians, world coordinates; ``start`` is the
centre of the car's box; ``side`` is where the road lies seen from the parked
car. Obstacle outlines are simple polygons (no self-crossings) of at least
three vertices, either orientation.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.parking.frames import LEFT, RIGHT, SlotFrame, axle_to_centre, wrap
from jaxplan.parking.scenes import ParkingScene
from jaxplan.types import VehicleParams

VEHICLE_FIELDS = ("length", "width", "wheelbase", "rear_overhang", "max_steer")
START_FIELDS = ("x", "y", "heading")
TOP_FIELDS = ("vehicle", "start", "road_heading", "side", "obstacles")
MAX_MISALIGNMENT_DEG = 45.0


class ParkoutProblem(NamedTuple):
    """A scene file, read and checked.

    Attributes:
        vehicle: the car.
        frame: the slot frame in the world.
        scene: one ``ParkingScene`` in the slot frame.
        polygons: the obstacle outlines as given, world frame, ``(n_i, 2)`` each.
        source: the file name (for messages).
    """

    vehicle: VehicleParams
    frame: SlotFrame
    scene: ParkingScene
    polygons: list
    source: str


class SceneError(ValueError):
    """A malformed scene file: the message names the file and the field."""


def _num(v, where, src):
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise SceneError(f"{src}: {where}: expected a number, got {json.dumps(v)[:40]}")
    if not math.isfinite(v):
        raise SceneError(f"{src}: {where}: must be finite, got {v}")
    return float(v)


def _obj(v, where, src, fields):
    if not isinstance(v, dict):
        raise SceneError(
            f"{src}: {where or 'scene'}: expected an object with {', '.join(fields)}, got {type(v).__name__}"
        )
    pre = f"{where}." if where else ""
    extra = sorted(set(v) - set(fields))
    if extra:
        raise SceneError(f"{src}: {pre}{extra[0]}: unknown field; allowed: {', '.join(fields)}")
    missing = [f for f in fields if f not in v]
    if missing:
        raise SceneError(f"{src}: {pre}{missing[0]}: missing")
    return v


def _segments_cross(p, q, a, b):
    """Proper crossings of segments p-q (..., 2) with a-b (..., 2) (numpy; touching is not)."""

    def orient(o, u, w):
        return (u[..., 0] - o[..., 0]) * (w[..., 1] - o[..., 1]) - (u[..., 1] - o[..., 1]) * (w[..., 0] - o[..., 0])

    d1, d2 = orient(a, b, p), orient(a, b, q)
    d3, d4 = orient(p, q, a), orient(p, q, b)
    return (d1 * d2 < 0) & (d3 * d4 < 0)


def _simple(poly):
    """No two non-adjacent edges of the closed polygon ``(N, 2)`` cross."""
    n = len(poly)
    p, q = poly, np.roll(poly, -1, 0)
    i, j = np.triu_indices(n, 2)
    keep = ~((i == 0) & (j == n - 1))
    i, j = i[keep], j[keep]
    return not np.any(_segments_cross(p[i], q[i], p[j], q[j]))


def _inside(pts, poly):
    """Crossing-number point-in-polygon, strict-ish (numpy): ``pts (P, 2)``, ``poly (N, 2)``."""
    x, y = pts[:, :1], pts[:, 1:]
    a, b = poly[None], np.roll(poly, -1, 0)[None]
    cross = (a[..., 1] > y) != (b[..., 1] > y)
    t = (y - a[..., 1]) / np.where(b[..., 1] == a[..., 1], 1.0, b[..., 1] - a[..., 1])
    xc = a[..., 0] + t * (b[..., 0] - a[..., 0])
    return np.sum(cross & (x < xc), axis=1) % 2 == 1


def _overlaps(box, poly):
    """Whether two simple polygons overlap with positive area (edges cross or one holds the other)."""
    bp, bq = box, np.roll(box, -1, 0)
    pp, pq = poly, np.roll(poly, -1, 0)
    cross = _segments_cross(bp[:, None], bq[:, None], pp[None], pq[None])
    # vertices nudged into their own outline, so that touching is not overlap
    inner = lambda pts, other: _inside(pts + 1e-7 * (pts.mean(0) - pts), other)  # noqa: E731
    return bool(np.any(cross) or np.any(inner(poly, box)) or np.any(inner(box, poly)))


def car_outline(centre_pose, vehicle):
    """Corners ``(4, 2)`` of the car's box at a box-centre pose (numpy), counter-clockwise."""
    x, y, th = centre_pose
    c, s = np.cos(th), np.sin(th)
    hl, hw = 0.5 * float(vehicle.length), 0.5 * float(vehicle.width)
    loc = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
    return np.array([x, y]) + loc @ np.array([[c, s], [-s, c]])


def problem_from_dict(d, source: str = "scene") -> ParkoutProblem:
    """Check a scene dict field by field (``SceneError`` names the field) and build the slot-frame scene."""
    src = source
    _obj(d, "", src, TOP_FIELDS)
    veh = _obj(d["vehicle"], "vehicle", src, VEHICLE_FIELDS)
    vals = {f: _num(veh[f], f"vehicle.{f}", src) for f in VEHICLE_FIELDS}
    for f in ("length", "width", "wheelbase", "max_steer"):
        if vals[f] <= 0:
            raise SceneError(f"{src}: vehicle.{f}: must be positive, got {vals[f]}")
    if vals["rear_overhang"] < 0:
        raise SceneError(f"{src}: vehicle.rear_overhang: must be >= 0, got {vals['rear_overhang']}")
    if vals["wheelbase"] + vals["rear_overhang"] > vals["length"]:
        raise SceneError(f"{src}: vehicle.wheelbase: wheelbase + rear_overhang exceeds length")
    if vals["max_steer"] >= math.radians(60):
        raise SceneError(
            f"{src}: vehicle.max_steer: {vals['max_steer']} rad is not below 60 degrees (angles are in radians)"
        )
    vehicle = VehicleParams(**vals)
    st = _obj(d["start"], "start", src, START_FIELDS)
    sx, sy, sh = (_num(st[f], f"start.{f}", src) for f in START_FIELDS)
    road = _num(d["road_heading"], "road_heading", src)
    side = d["side"]
    if side not in (LEFT, RIGHT):
        raise SceneError(f'{src}: side: must be "left" or "right", got {json.dumps(side)[:40]}')
    mis = abs(wrap(sh - road))
    mis = min(mis, math.pi - mis)
    if math.degrees(mis) > MAX_MISALIGNMENT_DEG:
        raise SceneError(
            f"{src}: start.heading: {math.degrees(mis):.0f} degrees from road_heading; a parallel "
            f"park-out needs the car within {MAX_MISALIGNMENT_DEG:.0f} degrees of the road"
        )
    obs = d["obstacles"]
    if not isinstance(obs, list):
        raise SceneError(f'{src}: obstacles: expected a list of {{"polygon": [[x, y], ...]}}')
    car = car_outline((sx, sy, sh), vehicle)
    polys = []
    for i, o in enumerate(obs):
        where = f"obstacles[{i}]"
        _obj(o, where, src, ("polygon",))
        pg = o["polygon"]
        if not isinstance(pg, list) or len(pg) < 3:
            raise SceneError(f"{src}: {where}.polygon: expected a list of at least 3 [x, y] points")
        pts = []
        for j, v in enumerate(pg):
            if not isinstance(v, list) or len(v) != 2:
                raise SceneError(f"{src}: {where}.polygon[{j}]: expected [x, y], got {json.dumps(v)[:40]}")
            pts.append([_num(v[0], f"{where}.polygon[{j}][0]", src), _num(v[1], f"{where}.polygon[{j}][1]", src)])
        p = np.asarray(pts, float)
        if np.any(np.all(p == np.roll(p, -1, 0), axis=1)):
            raise SceneError(f"{src}: {where}.polygon: repeated consecutive vertex")
        scale = max(1.0, float(np.abs(p - p.mean(0)).max()))
        area = 0.5 * np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
        if abs(area) <= 1e-9 * scale**2:
            raise SceneError(f"{src}: {where}.polygon: zero area")
        if not _simple(p):
            raise SceneError(f"{src}: {where}.polygon: edges cross each other (not a simple polygon)")
        if _overlaps(car, p):
            raise SceneError(f"{src}: {where}: overlaps the car's box at the start pose")
        polys.append(p)
    frame = SlotFrame.of_start((sx, sy), sh, road, side, vehicle)
    start = np.array([0.0, 0.0, float(frame.to_slot_heading(sh))])
    scene = slot_scene([frame.to_slot_xy(p) for p in polys], start)
    return ParkoutProblem(vehicle, frame, scene, polys, src)


def slot_scene(polygons, start, **sensor) -> ParkingScene:
    """One ``ParkingScene`` from slot-frame outlines (a list of ``(n_i, 2)``), padded by repeating
    each outline's last vertex; no obstacles gives one invalid dummy."""
    n = max([len(p) for p in polygons] + [3])
    arr = np.zeros((max(len(polygons), 1), n, 2))
    valid = np.zeros(len(arr), bool)
    for i, p in enumerate(polygons):
        arr[i, : len(p)] = p
        arr[i, len(p) :] = p[-1]
        valid[i] = True
    if not polygons:
        arr[0] = [[1e3, 1e3], [1e3 + 1, 1e3], [1e3, 1e3 + 1]]
    return ParkingScene.make(arr, valid, start, **sensor)


def stack_parking_scenes(scenes) -> ParkingScene:
    """One batch ``(n,)`` of single scenes with different obstacle and vertex counts (padded: extra
    vertices repeat the last one, extra obstacles are invalid copies)."""
    n = max(np.shape(s.polygons)[-2] for s in scenes)
    k = max(np.shape(s.polygons)[-3] for s in scenes)

    def pad(s):
        p = np.asarray(s.polygons)
        p = np.concatenate([p, np.repeat(p[:, -1:], n - p.shape[1], 1)], 1)
        v = np.asarray(s.valid)
        p = np.concatenate([p, np.repeat(p[-1:], k - p.shape[0], 0)], 0)
        v = np.concatenate([v, np.zeros(k - len(v), bool)])
        return dataclasses.replace(s, polygons=p, valid=v)

    return jax.tree_util.tree_map(
        lambda *a: jnp.asarray(np.stack([np.asarray(x) for x in a])), *[pad(s) for s in scenes]
    )


def load_problem(path: str) -> ParkoutProblem:
    """Read and check a scene file (``SceneError`` with the file and the field on any problem)."""
    if os.path.isdir(path):
        raise SceneError(f"{path}: is a directory, expected a scene JSON file")
    if not os.path.exists(path):
        raise SceneError(f"{path}: no such file")
    try:
        with open(path) as f:
            d = json.load(f)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise SceneError(f"{path}: not valid JSON ({err})") from None
    return problem_from_dict(d, path)


def result_states(result, problem: ParkoutProblem, config, speeds=None):
    """The driven states of one ``ParkoutResult`` in the world: ``(S, 4)`` [x, y, heading, gear] of the box
    centre, every move's points in order (a gear change repeats the pose with the new gear), and the
    matching signed speed and time ``(S,)`` each if ``speeds = (v, t)`` (``speed_profile``) is given."""
    poses, valid, gear = (np.asarray(a) for a in (result.poses, result.valid, result.gear))
    rows, vs, ts = [], [], []
    for m in range(len(gear)):
        if gear[m] == 0:
            continue
        q = poses[m][valid[m]]
        w = problem.frame.to_world_pose(q)
        c = axle_to_centre(w, problem.vehicle)
        rows.append(np.concatenate([c, np.full((len(c), 1), float(gear[m]))], 1))
        if speeds is not None:
            vs.append(np.asarray(speeds[0])[m][valid[m]])
            ts.append(np.asarray(speeds[1])[m][valid[m]])
    if not rows:
        start = axle_to_centre(problem.frame.to_world_pose(np.asarray(problem.scene.start)), problem.vehicle)
        return np.concatenate([start, [1.0]])[None], np.zeros(1), np.zeros(1)
    if speeds is None:
        return np.concatenate(rows), None, None
    return np.concatenate(rows), np.concatenate(vs), np.concatenate(ts)


def write_result(out_dir: str, success: bool, moves: int, states, v=None, t=None) -> str:
    """Write ``OUT/parkout.json`` (atomically) and return its path."""
    doc = {
        "success": bool(success),
        "moves": int(moves),
        "states": [[round(float(a), 4) for a in s[:3]] + [int(s[3])] for s in states],
    }
    if v is not None:
        doc["v"] = [round(float(a), 4) for a in v]
        doc["t"] = [round(float(a), 4) for a in t]
    path = os.path.join(out_dir, "parkout.json")
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(doc, f)
    os.replace(tmp, path)
    return path
