"""The peer harness's fixed settings: where the repository, the shared scenarios and the peers'
interpreters are, the script the child processes run, the route every planner follows, the car
and the step."""

from __future__ import annotations

import os

EXPERIMENTS = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOT = os.path.dirname(EXPERIMENTS)
ENTRY = os.path.join(EXPERIMENTS, "compare_peers.py")  # the script every child process runs (``--worker``)
DATA = os.path.join(os.path.dirname(ROOT), "shared", "data")
if not os.path.isdir(DATA):
    DATA = "/work/shared/data"
DEFAULT_SCENARIOS = [os.path.join(DATA, "commonroad2018a"), os.path.join(DATA, "commonroad2020a")]

# The reference path every planner follows: "module:function" taking a scenario file and returning
# its route as (N, 2) world points, called in the referee's environment; None = commonroad-route-planner
# in the reactive planner's venv.
ROUTE_BUILDER = "jaxplan.scenarios.files:world_route"  # the route every jaxplan planner drives on

# BMW 320i (CommonRoad vehicle type 2), the reactive planner's and Frenetix's default car.
CAR_LENGTH, CAR_WIDTH = 4.508, 1.61
DT = 0.1  # s: the harness's step
WB_REAR = 1.4227170936  # centre to rear axle
PEERS = ("reactive", "frenetix")
VENVS = {
    "reactive": "/work/venvs/reactive/bin/python",
    "frenetix": "/work/venvs/frenetix/bin/python",
    "referee": "/work/venvs/referee/bin/python",
}
