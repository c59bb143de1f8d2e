"""Native CommonRoad XML (2020a) in and out, through ``commonroad-io``.

Optional: ``pip install jaxplan[commonroad]``. A CommonRoad scenario is converted to
the shared JSON object and parsed by ``loader.parse_scenario``, so both formats end in
the same ``Scenario`` (local frame, same checks, same errors).

Files in and out here (``load_commonroad``, ``read_commonroad``, ``write_commonroad``, and
``write_solution`` for a planned trajectory); the conversions in ``from_commonroad`` (what a file
holds is read or refused out loud: its module docstring says what becomes of lights and obstacle
shapes) and ``to_commonroad``, the shapes in ``commonroad_shapes``.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from jaxplan.scenarios.commonroad_shapes import CIRCLE_SIDES, cover_box
from jaxplan.scenarios.fields import ScenarioError
from jaxplan.scenarios.from_commonroad import _speed_limits as _speed_limits
from jaxplan.scenarios.from_commonroad import commonroad_to_dict
from jaxplan.scenarios.loader import parse_scenario, read_bytes
from jaxplan.scenarios.scenario import Scenario
from jaxplan.scenarios.to_commonroad import _require, dict_to_commonroad

__all__ = [
    "CIRCLE_SIDES",
    "commonroad_to_dict",
    "cover_box",
    "dict_to_commonroad",
    "load_commonroad",
    "read_commonroad",
    "write_commonroad",
    "write_solution",
]


def write_commonroad(d: dict, path: str, name: str = "scenario", id_map: dict | None = None) -> str:
    """Write the shared JSON object as a CommonRoad 2020a XML file (see ``dict_to_commonroad``).

    Returns:
        ``path``.
    """
    from commonroad.common.file_writer import CommonRoadFileWriter, OverwriteExistingFile

    sc, pps = dict_to_commonroad(d, name, id_map)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    kw = {}
    try:  # commonroad-io 2026 writes protobuf unless told otherwise
        from commonroad.common.file_writer import FileFormat

        kw["file_format"] = FileFormat.XML
    except ImportError:
        pass
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        CommonRoadFileWriter(
            sc, pps, author="jaxplan", affiliation="", source=str(d.get("source", "")), tags=set(sc.tags or ()), **kw
        ).write_to_file(path, OverwriteExistingFile.ALWAYS)
    return path


def read_commonroad(path: str):
    """commonroad-io's ``(Scenario, PlanningProblemSet)`` of a CommonRoad XML file (``.xml``, or
    gzip-compressed ``.xml.gz``).

    Raises:
        ScenarioError: naming the file, when it is missing or commonroad-io cannot read it;
        ImportError: without the ``commonroad`` extra.
    """
    _require()
    from commonroad.common.file_reader import CommonRoadFileReader
    from commonroad.common.util import FileFormat

    raw = read_bytes(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return CommonRoadFileReader(raw, FileFormat.XML).open()
    except Exception as e:  # commonroad-io raises many kinds on malformed XML
        raise ScenarioError(f"{path}: not a readable CommonRoad XML file ({type(e).__name__}: {e})") from None


def load_commonroad(path: str, horizon: float | None = None) -> Scenario:
    """Read a CommonRoad XML file (``.xml`` or ``.xml.gz``) into a ``Scenario`` (local frame at the ego start)."""
    sc, pps = read_commonroad(path)
    notes: list = []
    try:
        d = commonroad_to_dict(sc, pps, notes=notes)
    except ScenarioError as e:
        raise ScenarioError(f"{path}: {e}") from None
    return parse_scenario(d, path, horizon, notes=notes)


def write_solution(
    scenario: Scenario,
    trajectory,
    path: str,
    planning_problem_id: int | None = None,
    vehicle_type: str = "BMW_320i",
    cost_function: str = "SM1",
) -> str:
    """Write a planned trajectory as a CommonRoad solution file (kinematic single-track states).

    Args:
        scenario: the scenario it was planned in (its ``origin`` maps back to world coordinates).
        trajectory: ``jaxplan.types.Trajectory`` with 1-D fields at the scenario's ``dt``.
        path: output directory.
        planning_problem_id: default the first planning problem of the scenario file.

    Returns:
        The written file's path.
    """
    _require()
    from commonroad.common.solution import (
        CommonRoadSolutionWriter,
        CostFunction,
        PlanningProblemSolution,
        Solution,
        VehicleModel,
        VehicleType,
    )
    from commonroad.scenario.scenario import ScenarioID
    from commonroad.scenario.state import KSState
    from commonroad.scenario.trajectory import Trajectory as CRTrajectory

    x, y = np.asarray(trajectory.x, float), np.asarray(trajectory.y, float)
    th, v = np.asarray(trajectory.theta, float), np.asarray(trajectory.v, float)
    t = np.asarray(trajectory.t, float)
    steps = np.rint(t / scenario.dt).astype(int)
    wheelbase = 2.578  # BMW 320i, the solution's vehicle type
    steer = np.arctan(wheelbase * np.asarray(trajectory.kappa, float))
    states = [
        KSState(
            time_step=int(k),
            position=np.array([x[i] + scenario.origin[0], y[i] + scenario.origin[1]]),
            steering_angle=float(steer[i]),
            velocity=float(v[i]),
            orientation=float(th[i]),
        )
        for i, k in enumerate(steps)
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sid = ScenarioID.from_benchmark_id(scenario.id, "2020a")
    pps = PlanningProblemSolution(
        planning_problem_id=int(planning_problem_id if planning_problem_id is not None else scenario.problem_id),
        vehicle_model=VehicleModel.KS,
        vehicle_type=VehicleType[vehicle_type],
        cost_function=CostFunction[cost_function],
        trajectory=CRTrajectory(int(steps[0]), states),
    )
    os.makedirs(path, exist_ok=True)
    writer = CommonRoadSolutionWriter(Solution(sid, [pps]))
    fname = f"solution_{scenario.id}.xml"
    writer.write_to_file(output_path=path, filename=fname, overwrite=True)
    return os.path.join(path, fname)
