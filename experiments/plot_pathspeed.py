"""Picture of one ``pathspeed`` cycle: the path in its bounds (map, SL) and the ST graph.

    PYTHONPATH=$PWD python experiments/plot_pathspeed.py --kind parked_cars --out docs/img/pathspeed_parked.png
    PYTHONPATH=$PWD python experiments/plot_pathspeed.py --scenario FILE --step 30 --out x.png

The cycle is planned at ``--step`` of the scene from the car's recorded start state (built-in
scenes: the first survivable scene of ``--kind``; ``--scenario``: a recorded scenario file).
"""
from __future__ import annotations

import argparse
import sys


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kind", default="parked_cars", help="built-in scene kind")
    ap.add_argument("--scenario", default=None, help="recorded scenario file (.json / .xml) instead")
    ap.add_argument("--step", type=int, default=0, help="scene step of the cycle (>= 0)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True, help="PNG file")
    a = ap.parse_args(argv)
    if a.step < 0:
        print("plot_pathspeed: --step must be >= 0", file=sys.stderr)
        return 2
    from jaxplan.planner import EgoState, make_planner
    from jaxplan.speed.plot import plot_cycle

    if a.scenario:
        from jaxplan.scenarios.files import load_records

        rec = load_records([a.scenario])[0]
    else:
        from jaxplan.scenarios.builtin import KINDS

        if a.kind not in KINDS:
            print(f"plot_pathspeed: --kind must be one of {', '.join(KINDS)}", file=sys.stderr)
            return 2
        from jaxplan.scenarios.builtin import _generate

        rec = _generate(1, a.seed, (a.kind,))[0][1]
    planner = make_planner("pathspeed")
    ego = EgoState.from_box_centre(rec.scene.start, planner.vehicle)
    print(plot_cycle(a.out, planner, rec.scene, ego, a.step, rec.name))
    return 0


if __name__ == "__main__":
    sys.exit(main())
