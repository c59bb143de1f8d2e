"""The road of a scenario object (the shared JSON format) read into the local frame: lanelets as
``Lane``s (bounds, centre line, successors and predecessors, neighbours by driving direction,
speed limit), the map's traffic lights as ``TrafficLight``s, and each lanelet's light references
and stop line. Malformed fields raise ``ScenarioError`` naming the file and field.
"""

from __future__ import annotations

import numpy as np

from jaxplan.scenarios.fields import ScenarioError, _field, _ids, _int, _number, _points
from jaxplan.scenarios.scenario import LIGHT_COLORS, LIGHT_DIRECTIONS, Lane, TrafficLight


def _adjacent(ln: dict, key: str, where: str, path: str, same: bool = True) -> int | None:
    """Id of the neighbour lanelet driven the same way (``same``) or the other way, or None."""
    v = ln.get(key)
    if v is None:
        return None
    if not isinstance(v, dict):
        raise ScenarioError(f"{path}: field {where}.{key} should be an object")
    direction = v.get("drivingDir", "same")
    if direction not in ("same", "opposite"):
        raise ScenarioError(f"{path}: field {where}.{key}.drivingDir should be 'same' or 'opposite', got {direction!r}")
    if (direction == "same") != same:
        return None
    return _int(v, "ref", f"{where}.{key}", path)


def _traffic_lights(d: dict, dt: float, t0: float, origin: np.ndarray, path: str) -> tuple:
    """The scenario's ``TrafficLight``s (optional field ``traffic_lights``), on the scene's clock."""
    raw = d.get("traffic_lights")
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise ScenarioError(f"{path}: field scenario.traffic_lights should be a list of objects")
    out, seen = [], set()
    for i, tl in enumerate(raw):
        where = f"traffic_lights[{i}]"
        if not isinstance(tl, dict):
            raise ScenarioError(f"{path}: field {where} should be an object")
        lid = _int(tl, "id", where, path)
        if lid in seen:
            raise ScenarioError(f"{path}: field {where}.id {lid} is used by another traffic light")
        seen.add(lid)
        direction = tl.get("direction", "all")
        if direction not in LIGHT_DIRECTIONS:
            raise ScenarioError(
                f"{path}: field {where}.direction should be one of {', '.join(LIGHT_DIRECTIONS)}, got {direction!r}"
            )
        active = tl.get("active", True)
        if not isinstance(active, bool):
            raise ScenarioError(f"{path}: field {where}.active should be true or false, got {active!r}")
        offset = _number(tl, "time_offset", where, path) if tl.get("time_offset") is not None else 0.0
        cycle = tl.get("cycle") or []
        if not isinstance(cycle, list):
            raise ScenarioError(f"{path}: field {where}.cycle should be a list of {{color, duration}} phases")
        if active and not cycle:
            raise ScenarioError(f"{path}: field {where}.cycle is empty (an active light needs its phases)")
        colors, durations = [], []
        for j, ph in enumerate(cycle):
            w = f"{where}.cycle[{j}]"
            if not isinstance(ph, dict):
                raise ScenarioError(f"{path}: field {w} should be an object {{color, duration}}")
            color = ph.get("color")
            if color not in LIGHT_COLORS:
                raise ScenarioError(
                    f"{path}: field {w}.color should be one of {', '.join(LIGHT_COLORS)}, got {color!r}"
                )
            dur = _number(ph, "duration", w, path)
            steps = int(round(dur / dt))
            if dur <= 0 or steps < 1 or steps > 1e7:
                raise ScenarioError(
                    f"{path}: field {w}.duration should be at least one time step ({dt:g} s) and finite, got {dur!r}"
                )
            colors.append(color)
            durations.append(steps)
        pos = None
        if tl.get("position") is not None:
            pos = _points([tl["position"]], f"{where}.position", path)[0] - origin
        out.append(
            TrafficLight(lid, direction, active, tuple(colors), tuple(durations), int(round((offset - t0) / dt)), pos)
        )
    return tuple(out)


def _lane_lights(
    ln: dict, where: str, path: str, left: np.ndarray, right: np.ndarray, origin: np.ndarray, known: set
) -> tuple:
    """``(light ids, stop line (2, 2) or None)`` of a lanelet (optional ``traffic_lights`` and ``stop_line``)."""
    ids = set(_ids(ln, "traffic_lights", where, path))
    sl = ln.get("stop_line")
    line = None
    if sl is not None:
        w = f"{where}.stop_line"
        if not isinstance(sl, dict):
            raise ScenarioError(f"{path}: field {w} should be an object {{start, end, traffic_lights}}")
        ids |= set(_ids(sl, "traffic_lights", w, path))
        has = [sl.get(k) is not None for k in ("start", "end")]
        if any(has) and not all(has):
            raise ScenarioError(f"{path}: field {w} gives only one of start and end")
        if all(has):
            line = (
                np.stack([_points([sl["start"]], f"{w}.start", path)[0], _points([sl["end"]], f"{w}.end", path)[0]])
                - origin
            )
    missing = sorted(ids - known)
    if missing:
        raise ScenarioError(f"{path}: field {where}.traffic_lights names traffic lights that do not exist: {missing}")
    if line is None and (sl is not None or ids):  # the line lies across the lanelet's end
        line = np.stack([left[-1], right[-1]])
    return tuple(sorted(ids)), line


def _lanes(d: dict, origin: np.ndarray, light_ids: set, path: str) -> list:
    """The scenario's ``lanelets`` as ``Lane``s shifted by ``origin`` (``light_ids``: the lights that exist)."""
    lanes = []
    for i, ln in enumerate(_field(d, "lanelets", "scenario", path, list)):
        where = f"lanelets[{i}]"
        left = _points(_field(ln, "left", where, path), f"{where}.left", path, 2) - origin
        right = _points(_field(ln, "right", where, path), f"{where}.right", path, 2) - origin
        if left.shape != right.shape:
            raise ScenarioError(f"{path}: field {where}.left and .right differ in length")
        limit = ln.get("speed_limit")
        if limit is not None:
            limit = _number(ln, "speed_limit", where, path)
        refs, stop_line = _lane_lights(ln, where, path, left, right, origin, light_ids)
        lanes.append(
            Lane(
                _int(ln, "id", where, path),
                left,
                right,
                0.5 * (left + right),
                _ids(ln, "successors", where, path),
                _ids(ln, "predecessors", where, path),
                _adjacent(ln, "adjacentLeft", where, path),
                _adjacent(ln, "adjacentRight", where, path),
                limit,
                _adjacent(ln, "adjacentLeft", where, path, same=False),
                _adjacent(ln, "adjacentRight", where, path, same=False),
                refs,
                stop_line,
            )
        )
    return lanes
