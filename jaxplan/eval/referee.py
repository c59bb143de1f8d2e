"""Independent referee of closed-loop drives: commonroad-drivability-checker and commonroad-io.

Judges a drive, the ``driven.json`` that ``jaxplan drive`` and the peer comparison write::

    {"scenario": key, "planner": name, "dt": 0.1, "vehicle": {"length": L, "width": W},
     "states": [[t, x, y, theta, v, a], ...]}

(``(x, y)`` the centre of the car's box in the scenario's world coordinates, ``t`` from the
scenario start, one row per ``dt``), against its scenario (shared JSON, converted with
``jaxplan.scenarios.to_commonroad.dict_to_commonroad``, or CommonRoad XML), with nothing of
jaxplan's geometry:

* collision: the car's box (``L x W`` at the row's pose) against the scenario's
  ``create_collision_checker`` at that time step (every obstacle, static ones at every step,
  dynamic ones while their recording lasts); the obstacle(s) hit are named by testing each
  obstacle's own collision object at the first colliding step;
* off road: the same box is not enclosed by the union of the lanelets
  (``obb_enclosure_polygons_static`` over ``create_road_polygons(method="lanelet_polygons")``,
  buffered by ``ROAD_TOL`` = 5 cm so that neighbouring lanelets whose shared bound has
  different vertices leave no sliver between them (``USA_US101-10_1_T-1`` has a 10 m long gap up
  to 4 cm wide between two lanes: a map seam, not the road's edge);
* road boundary contact (``boundary_contact``, reported beside it): the box against
  ``create_road_boundary_obstacle`` (oriented rectangles along the contours of the lanelets'
  union, open at lane ends without successor or predecessor, as the reactive planner and
  Frenetix use it). It differs from "off road" where the map's lanes end (open there) and where
  a shared bound's vertices differ (a sliver hole whose contour counts as road boundary, e.g.
  ``DEU_Muc-2_1``'s two lanes);
* goal: ``PlanningProblem.goal.is_reached`` on every row (time step, position, orientation,
  velocity; the goal's own rule), first time reached.

Optional dependency: ``pip install 'jaxplan[referee]'`` (commonroad-drivability-checker 2025.4.0,
which imports ``commonroad.geometry.shape`` and so needs commonroad-io < 2026).

CLI-ish entry: ``experiments/compare_peers.py --judge-only``.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

EXTRA = "referee"
ROAD_TOL = 0.05  # m: lanelet polygons are buffered by this (jaxplan's off-road metric uses the same tolerance)


def require_referee():
    """Import the referee's tools or raise one line naming the extra."""
    try:
        import commonroad  # noqa: F401
        import commonroad_dc  # noqa: F401
    except ImportError:
        raise ImportError(
            f"the referee needs commonroad-drivability-checker and commonroad-io: pip install 'jaxplan[{EXTRA}]'"
        ) from None
    try:
        from commonroad_dc.boundary import boundary  # noqa: F401
        from commonroad_dc.collision.collision_detection import pycrcc_collision_dispatch  # noqa: F401
    except ImportError as e:
        import importlib.metadata as md

        try:
            have = md.version("commonroad-io")
        except md.PackageNotFoundError:
            have = "?"
        raise ImportError(
            f"commonroad-drivability-checker cannot load with commonroad-io {have} ({e}); "
            f"it needs commonroad-io < 2026: pip install 'jaxplan[{EXTRA}]'"
        ) from None


class DriveError(ValueError):
    """A driven.json that cannot be judged; the message names the file and field."""


def load_driven(path: str) -> dict:
    """Read and check one ``driven.json`` (see the module docstring).

    Returns:
        The object with ``states`` as a float ``(N, 6)`` array.
    """
    try:
        with open(path) as f:
            d = json.load(f)
    except (OSError, ValueError) as e:
        raise DriveError(f"{path}: not a readable JSON file ({e})") from None
    if not isinstance(d, dict):
        raise DriveError(f"{path}: top level should be an object")
    for key in ("scenario", "planner", "dt", "vehicle", "states"):
        if key not in d:
            raise DriveError(f"{path}: missing field {key}")
    v = d["vehicle"]
    if not isinstance(v, dict) or not all(isinstance(v.get(k), (int, float)) and v[k] > 0 for k in ("length", "width")):
        raise DriveError(f"{path}: field vehicle should be {{'length': L, 'width': W}} with positive sizes")
    if not isinstance(d["dt"], (int, float)) or not d["dt"] > 0:
        raise DriveError(f"{path}: field dt should be a positive number")
    try:
        st = np.asarray(d["states"], dtype=np.float64)
    except (TypeError, ValueError):
        st = None
    if st is None or st.ndim != 2 or st.shape[1] != 6 or len(st) < 1:
        raise DriveError(f"{path}: field states should be rows [t, x, y, theta, v, a]")
    if not np.all(np.isfinite(st)):
        raise DriveError(f"{path}: field states holds NaN or inf (row {int(np.argwhere(~np.isfinite(st))[0, 0])})")
    steps = st[:, 0] / float(d["dt"])
    if len(st) > 1 and not np.allclose(np.diff(steps), 1.0, atol=1e-3):
        bad = int(np.argmax(~np.isclose(np.diff(steps), 1.0, atol=1e-3)))
        raise DriveError(
            f"{path}: field states should have one row per dt (rows {bad} and {bad + 1} are "
            f"{st[bad + 1, 0] - st[bad, 0]:g} s apart)"
        )
    d["states"] = st
    return d


def _open(path: str):
    """``(scenario, planning problem, id map)`` of a scenario file (``.json`` / ``.xml``, either ``.gz``)."""
    from jaxplan.scenarios.commonroad import read_commonroad
    from jaxplan.scenarios.files import scenario_format
    from jaxplan.scenarios.loader import read_bytes
    from jaxplan.scenarios.to_commonroad import dict_to_commonroad

    if scenario_format(path) == "json":
        id_map: dict = {}
        sc, pps = dict_to_commonroad(json.loads(read_bytes(path)), path, id_map)
    else:
        sc, pps = read_commonroad(path)
        id_map = {}
    problems = list(pps.planning_problem_dict.values())
    if not problems:
        raise ValueError(f"{path}: no planning problem")
    return sc, problems[0], id_map


class Referee:
    """The verdicts on drives in one scenario (collision checker and road boundary built once).

    Args:
        scenario: commonroad-io ``Scenario``.
        planning_problem: the problem whose goal counts.
        id_map: CommonRoad obstacle id -> id to report (``dict_to_commonroad`` renumbers clashes).
    """

    def __init__(self, scenario, planning_problem, id_map: dict | None = None):
        require_referee()
        from commonroad_dc.boundary.boundary import create_road_boundary_obstacle
        from commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch import (
            create_collision_checker,
            create_collision_object,
        )

        self.scenario, self.problem, self.id_map = scenario, planning_problem, dict(id_map or {})
        self.dt = float(scenario.dt)
        from commonroad_dc.boundary.boundary import create_road_polygons

        self.cc = create_collision_checker(scenario)
        _, self.road = create_road_boundary_obstacle(scenario, method="obb_rectangles")
        # triangulated: without, pycrcc stands each polygon in for its bounding box
        self.lanelets = create_road_polygons(
            scenario, method="lanelet_polygons", buffer=1, buf_width=ROAD_TOL, triangulate=True
        )
        self.objects = [
            (int(self.id_map.get(o.obstacle_id, o.obstacle_id)), create_collision_object(o), False)
            for o in scenario.static_obstacles
        ]
        self.objects += [
            (int(self.id_map.get(o.obstacle_id, o.obstacle_id)), create_collision_object(o), True)
            for o in scenario.dynamic_obstacles
        ]

    @classmethod
    def from_file(cls, path: str) -> Referee:
        """A referee for a shared-JSON or CommonRoad XML scenario file."""
        require_referee()
        return cls(*_open(path))

    def _box(self, x, y, th, length, width):
        from commonroad_dc import pycrcc

        return pycrcc.RectOBB(0.5 * length, 0.5 * width, float(th), float(x), float(y))

    def hit(self, k: int, box) -> list[int]:
        """Ids of the obstacles whose own collision object touches ``box`` at time step ``k``."""
        out = []
        for oid, obj, dynamic in self.objects:
            if dynamic:
                if not obj.time_start_idx() <= k <= obj.time_end_idx():
                    continue
                obj = obj.obstacle_at_time(k)
            if obj.collide(box):
                out.append(oid)
        return out

    def judge(self, states, length: float, width: float) -> dict:
        """Verdict on one drive.

        Args:
            states: ``(N, 6)`` rows ``[t, x, y, theta, v, a]`` (world coordinates, box centre).
            length, width: the car's box (m).

        Returns:
            ``collided``, ``first_collision_time``, ``collision_obstacles`` (ids hit then),
            ``off_road``, ``first_off_road_time``, ``goal_reached``, ``goal_time``, ``steps``,
            ``end_time`` (times in s from the scenario start).
        """
        from commonroad.scenario.state import KSState

        st = np.asarray(states, np.float64)
        ks = np.rint(st[:, 0] / self.dt).astype(int)
        from commonroad_dc.collision.trajectory_queries.trajectory_queries import obb_enclosure_polygons_static

        first_col = first_off = first_edge = goal = None
        hit: list[int] = []
        for k, (_t, x, y, th, v, _a) in zip(ks, st):
            box = self._box(x, y, th, length, width)
            if first_col is None and self.cc.time_slice(int(k)).collide(box):
                first_col, hit = int(k), self.hit(int(k), box)
            # it returns [enclosed, error]: an error is not a verdict
            enclosed, failed = obb_enclosure_polygons_static(self.lanelets, box)
            if failed:
                raise RuntimeError(f"drivability checker could not decide road enclosure at step {k}")
            if first_off is None and not enclosed:
                first_off = int(k)
            if first_edge is None and self.road.collide(box):
                first_edge = int(k)
            if goal is None and self.problem.goal.is_reached(
                KSState(
                    time_step=int(k),
                    position=np.array([x, y]),
                    orientation=float(math.remainder(th, 2 * math.pi)),
                    velocity=float(v),
                    steering_angle=0.0,
                )
            ):
                goal = int(k)
        t = lambda k: None if k is None else round(k * self.dt, 6)  # noqa: E731
        return {
            "collided": first_col is not None,
            "first_collision_time": t(first_col),
            "collision_obstacles": hit,
            "off_road": first_off is not None,
            "first_off_road_time": t(first_off),
            "boundary_contact": first_edge is not None,
            "first_boundary_contact_time": t(first_edge),
            "goal_reached": goal is not None,
            "goal_time": t(goal),
            "steps": int(len(st) - 1),
            "end_time": t(int(ks[-1])),
        }


def judge_file(referee: Referee, path: str, key: str | None = None) -> dict:
    """Verdict on one ``driven.json`` (checked first), with its scenario key and planner."""
    d = load_driven(path)
    if key is not None and str(d["scenario"]) != key:
        raise DriveError(f"{path}: field scenario is {d['scenario']!r}, expected {key!r} (the folder's scenario)")
    if not math.isclose(float(d["dt"]), referee.dt, rel_tol=1e-6):
        raise DriveError(f"{path}: field dt is {d['dt']}, the scenario's is {referee.dt}")
    t0 = float(referee.problem.initial_state.time_step) * referee.dt
    if abs(d["states"][0, 0] - t0) > 1e-6:
        raise DriveError(
            f"{path}: field states starts at t = {d['states'][0, 0]:g} s, the scenario's start is {t0:g} s"
        )
    v = referee.judge(d["states"], float(d["vehicle"]["length"]), float(d["vehicle"]["width"]))
    return {"scenario": str(d["scenario"]), "planner": str(d["planner"]), **v}


def summarize(verdicts: list) -> dict:
    """Counts over one planner's rows.

    ``goal_share`` is goals reached over all scenarios (a scenario without a judged drive counts
    as not reached); ``collision_share`` and ``off_road_share`` are over the judged drives.
    """
    judged = [v for v in verdicts if "goal_reached" in v]
    n, total = len(judged), len(verdicts)
    count = lambda k: sum(bool(v[k]) for v in judged)  # noqa: E731
    return {
        "scenarios": total,
        "judged": n,
        "goal_reached": count("goal_reached"),
        "collided": count("collided"),
        "off_road": count("off_road"),
        "goal_share": count("goal_reached") / total if total else None,
        "collision_share": count("collided") / n if n else None,
        "off_road_share": count("off_road") / n if n else None,
    }


def judge_folders(folders: dict, scenarios: dict, progress=None) -> dict:
    """Judge every ``<folder>/<key>/driven.json`` of several planners against their scenarios.

    Args:
        folders: ``{label: folder}``, each holding ``<key>/driven.json`` per scenario.
        scenarios: ``{key: scenario file}`` (``jaxplan.scenarios.files.scenario_keys``).
        progress: optional callable(str) told of each scenario.

    Returns:
        ``{"drives": {label: [row, ...]}, "summary": {label: counts}}``; a scenario a folder has
        no drive for is a row with ``"missing": true``, a scenario that cannot be refereed a row with
        ``"error"`` (and no verdict).
    """
    rows: dict = {label: [] for label in folders}
    for key, path in scenarios.items():
        if progress:
            progress(key)
        try:
            ref = Referee.from_file(path)
            err = None
        except ImportError:
            raise
        except Exception as e:  # noqa: BLE001 - a scenario the tools cannot build is reported, not fatal
            ref, err = None, f"{type(e).__name__}: {e}"
        for label, folder in folders.items():
            f = os.path.join(folder, key, "driven.json")
            if not os.path.exists(f):
                rows[label].append({"scenario": key, "missing": True})
            elif ref is None:
                rows[label].append({"scenario": key, "error": f"scenario not refereed: {err}"})
            else:
                try:
                    rows[label].append(judge_file(ref, f, key))
                except DriveError as e:
                    rows[label].append({"scenario": key, "error": str(e)})
    return {"drives": rows, "summary": {label: summarize(r) for label, r in rows.items()}}
