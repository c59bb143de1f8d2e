"""Peers in jaxplan's closed-loop harness: the CommonRoad reactive planner and Frenetix, one referee.

Every planner drives the same scenarios in closed loop: it re-plans every ``--replan`` steps of
0.1 s (default 3 = 0.3 s) from the state it has reached, and the car follows the chosen plan
exactly (perfect tracking). All follow the same route (the reference path of ``routes.json``),
get the same set speed, and drive the BMW 320i (4.508 m x 1.61 m, the reactive planner's and
Frenetix's car). A drive ends when the goal is reached (CommonRoad's rule, on the car's centre),
at the end of the goal's time interval, or after ``--max-steps``. When a planner finds no
trajectory (or raises), the car goes on along its previous plan and the planner tries again next
step; with no plan left, the car brakes straight ahead at 8 m/s^2 (to a stand) and the planner
tries again every step.

Peers, each in its own virtual environment (their pins conflict with jaxplan's commonroad-io
2026.1); this script runs itself there as child processes (``--worker``), trajectories go
through JSON files:

* ``reactive``: ``commonroad-reactive-planner==2025.1`` (pins commonroad-io 2024.x), configured
  as its shipped scenario configurations: 2 s horizon (``--reactive-horizon-steps 20``),
  shortest sampled duration ``--reactive-t-min 1.0``, its sampling levels and cost function;
  it plans from the rear axle, so the route is extended 10 m straight backwards.
* ``frenetix``: ``frenetix==0.4.0`` (the C++ sampler and cost/feasibility functions; the
  ``frenetix-motion-planner`` 2024.1.1 package needs Python < 3.11) with the sampling loop of
  Frenetix's motion planner written here: 3 s horizon, end times 1.1..3 s, lateral offsets
  -3..3 m, end speeds in [v - 0.5 a_max T, v + a_max T / 7] at sampling level 2, its shipped
  cost weights (jerk, velocity offset to the set speed, distance to the reference path,
  collision probability of the recorded futures), its feasibility checks (yaw rate,
  acceleration, curvature, curvature rate), then the cheapest candidate that
  commonroad-drivability-checker finds free of every obstacle and of the road boundary; none
  free: its "stopping" emergency choice (lowest end speed, shortest, nearest offset).

Both peers see every obstacle's recorded future (as CommonRoad benchmarks do), static ones at
every time. Set speed (the same for every planner, from the scenario, never the current speed):
the middle of the goal's speed interval where the goal gives one, else the speed limit of the
start lanelet, else the speed that reaches the goal region's centre along the route at the
middle of the goal's time interval (clipped to 2..36 m/s), else the start speed.

Route: ``--routes FILE`` (``{"routes": {key: [[x, y], ...]}}``, world coordinates), else built by
``ROUTE_BUILDER`` (``experiments/peers/config.py``): jaxplan's route
(``jaxplan.scenarios.files.world_route``: the route to the goal lanelets that jaxplan's planners
drive on, in world coordinates), so every planner follows the same route; ``ROUTE_BUILDER = None``
uses commonroad-route-planner's shortest reference path.

Scenarios: ``--scenarios`` takes files and folders (searched recursively, as
``jaxplan.scenarios.files.expand_paths`` does): shared JSON and CommonRoad 2020a XML, either
gzip-compressed (``.json.gz``, ``.xml.gz``; the peers' workers decompress in memory).
``--sample N --seed S`` drives ``jaxplan.scenarios.files.sample_files`` of the expanded list (seeded,
stratified by folder). The chosen files go to ``sample.json`` (``files``, ``keys``) and
``sample.txt`` (one a line), so jaxplan's planners can later drive exactly the same files:
``jaxplan drive $(cat OUT/sample.txt) --planner NAME --out DIR --replan-every 3 --max-steps 300``,
then ``--judge-only --drives NAME=DIR`` here (same ``--scenarios --sample --seed``).

Resume: a scene whose ``<peer>/<key>/cycles.json`` exists (written last, when the drive is over,
also when the peer found no plan or failed) is not driven again; ``--redo`` drives it again. The
scenario facts and routes are kept in ``prep.json`` and reused while the file list is the same.
An interrupted run is resumed by running the same command again.

Settings: every run prints, and ``report.md`` holds, a table of the settings that differ between
the planners (horizon, sampling, set speed rule, ...; jaxplan's road planners' horizon and car read
from jaxplan) with the reason, and of those that are equal.

A scene a peer cannot drive is never dropped: a setup failure (the scenario or its route cannot be
built) is a ``not run: ...`` status, a peer that raises at setup a ``setup failed: ...`` status, a
planning call that raises is recorded in ``cycles.json`` (the car goes on as when no plan is
found); the report lists every such scene with its reason.

Referee (``jaxplan.eval.referee``, commonroad-drivability-checker + commonroad-io's goal check)
judges every folder in the same run: the peers' and, with ``--drives LABEL=DIR`` or
``--jaxplan NAME``, jaxplan's ``jaxplan drive`` output. It runs under ``--referee-python``, an
environment with jaxplan's dependencies and ``jaxplan[referee]`` (commonroad-io < 2026); default
``/work/venvs/referee`` where it exists, else the interpreter running this script (jaxplan's venv
with ``jaxplan[referee]`` serves). The referee opens scenario files by name; here it reads
``.gz`` files too (decompressed in memory, the same scenario objects).

Outputs in ``--out``: ``<peer>/<key>/driven.json`` (the format ``jaxplan drive`` writes) and
``<peer>/<key>/cycles.json`` (status, wall and CPU time of each planning call, the drive's wall
time), ``sample.json`` and ``sample.txt`` (the files driven), ``prep.json``, ``routes.json``,
``scenarios.json`` (set speed, steps, setup notes), ``compare_peers.json`` (every verdict, the
summary, counts per scenario folder, the settings table) and ``report.md`` (the tables).
``<key>`` is the scenario id, made unique as ``jaxplan.scenarios.files.scenario_keys`` does.
Success: a judged drive that reached the goal with no collision and without leaving the road.

Setup (once)::

    python3 -m venv /work/venvs/reactive && /work/venvs/reactive/bin/pip install commonroad-reactive-planner==2025.1
    python3 -m venv /work/venvs/frenetix && /work/venvs/frenetix/bin/pip install frenetix==0.4.0 \\
        commonroad-io==2024.3 commonroad-drivability-checker==2025.4.0
    python3 -m venv /work/venvs/referee && /work/venvs/referee/bin/pip install -e '.[referee]' \\
        'commonroad-io==2024.3'

(or ``--referee-python .venv/bin/python`` where jaxplan's venv has ``jaxplan[referee]``).

Run (from the repository root; both peers on all 50 shared scenarios)::

    .venv/bin/python experiments/compare_peers.py --out results/peers

The final comparison with jaxplan's planners in the same run (``jaxplan drive`` runs first, under
this interpreter, on the same files, the sample where ``--sample`` is given, into
``results/peers/jaxplan-<name>``)::

    .venv/bin/python experiments/compare_peers.py --out results/peers --jaxplan lattice pathspeed

Judge existing folders only (no driving)::

    .venv/bin/python experiments/compare_peers.py --out results/peers --judge-only --drives lattice=results/drive

A seeded sample of the gzip-compressed dev set, peers only (long: run it in the background; the
same command resumes)::

    nice -n 10 .venv/bin/python experiments/compare_peers.py --scenarios ../shared/data/commonroad \\
        --sample 200 --seed 0 --max-steps 300 --out results/peers200 --referee-python .venv/bin/python

Timings are per planning call (wall and process CPU time, peers single-threaded); on a shared
machine they are noisy.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # experiments/: the package peers
from peers import harness  # noqa: E402
from peers.harness import child, select_files, set_speed  # noqa: E402
from peers.report import plot_drives, render_report  # noqa: E402
from peers.settings import render_settings, settings_table  # noqa: E402
from peers.summary import agreement, jaxplan_verdicts  # noqa: E402
from peers.workers import (  # noqa: E402
    frenetix_worker,
    judge_worker,
    prep_worker,
    reactive_worker,
    route_worker,
    worker_main,
)

__all__ = [
    "main",
    "child",
    "select_files",
    "set_speed",
    "plot_drives",
    "render_report",
    "render_settings",
    "settings_table",
    "agreement",
    "jaxplan_verdicts",
    "frenetix_worker",
    "judge_worker",
    "prep_worker",
    "reactive_worker",
    "route_worker",
    "worker_main",
]


def main(argv=None) -> dict:
    """The command line above (``peers.harness.main``); ``--worker NAME`` runs one child job."""
    return harness.main(argv, description=__doc__.split("\n")[0])


if __name__ == "__main__":
    main()
