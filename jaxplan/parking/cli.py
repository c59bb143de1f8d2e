"""``jaxplan parkout SCENE.json --out DIR``: plan a park-out from a scene file.

Writes ``DIR/parkout.json`` (success, moves, the driven states of the box centre
with their gear, and the speed profile) and ``DIR/parkout.png``. A malformed
scene file gets one line naming the file and the field, and exit status 2.
"""

from __future__ import annotations

import os
import sys

from jaxplan import cli_args as ca


def add_parser(subparsers):
    """Register the ``parkout`` command on an ``argparse`` sub-parser set."""
    p = subparsers.add_parser(
        "parkout",
        help="plan a park-out from a scene JSON file; write OUT/parkout.json and OUT/parkout.png",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("scene", help="scene JSON file (format: see the README, section 'Park-out scene files')")
    p.add_argument(
        "--out", type=ca.output_dir, default="results/parkout", help="output directory (default: results/parkout)"
    )
    p.add_argument("--no-plot", action="store_true", help="skip the PNG")
    return p


def _fail(msg: str) -> int:
    print(f"jaxplan parkout: error: {msg}", file=sys.stderr)
    return 2


def run(args) -> int:
    """Run the command; returns the exit status (0 planned, also when no way out was found; 2 bad input)."""
    from jaxplan.parking.scene_file import SceneError, load_problem

    try:
        problem = load_problem(args.scene)
    except SceneError as err:
        return _fail(str(err))
    import json

    from jaxplan.parking.circles import stop_line
    from jaxplan.parking.config import ParkoutConfig
    from jaxplan.parking.driver import park_out, render_scenes
    from jaxplan.parking.profile import speed_profile_jit
    from jaxplan.parking.scene_file import result_states, write_result

    config = ParkoutConfig.for_vehicle(problem.vehicle)
    res = park_out(problem.scene, 0, config, problem.vehicle)
    v, t = speed_profile_jit(res.steer, res.valid, res.gear, config)
    states, vs, ts = result_states(res, problem, config, (v, t))
    os.makedirs(args.out, exist_ok=True)
    path = write_result(args.out, bool(res.success), int(res.moves), states, vs, ts)
    if not args.no_plot:
        import jax

        from jaxplan.parking.plot import save_plot

        one = jax.tree_util.tree_map(lambda a: a[None], problem.scene)
        cells = render_scenes(one, 0, config, problem.vehicle).cells[0]
        save_plot(
            os.path.join(args.out, "parkout.png"),
            problem.polygons,
            res,
            problem.vehicle,
            config,
            frame=problem.frame,
            cells=cells,
            stop_y=float(stop_line(problem.vehicle, config.c)),
            title=f"{os.path.basename(args.scene)}: {'out' if bool(res.success) else 'no way out found'}, "
            f"{int(res.moves)} moves, {float(res.path_length):.1f} m",
        )
    print(
        json.dumps(
            {
                "success": bool(res.success),
                "moves": int(res.moves),
                "path_length_m": round(float(res.path_length), 3),
                "states": int(len(states)),
            }
        )
    )
    print(f"wrote {path}")
    return 0
