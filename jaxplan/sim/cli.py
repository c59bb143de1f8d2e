"""``jaxplan drive PATHS... --planner NAME --out DIR``: closed-loop drives (see ``jaxplan.sim.drive``)."""
from __future__ import annotations

import sys

from jaxplan import cli_args as ca


def add_parser(sub) -> None:
    d = sub.add_parser("drive", help="drive scenarios in closed loop with a planner; write drives, metrics, report",
                       description=__doc__)
    d.add_argument("paths", nargs="*", help="scenario files (.json shared format, .xml CommonRoad) or folders of them")
    d.add_argument("--builtin", action="store_true", help="also drive the built-in synthetic scenes")
    d.add_argument("--planner", default="lattice",
                   help="planner name, several separated by commas, or 'all' (every planner that loads, "
                        "the baselines brake and idm included)")
    d.add_argument("--out", required=True, type=ca.output_dir, help="output folder")
    d.add_argument("--replan-every", type=ca.positive_int, default=3, help="steps between re-plans (default 3 = 0.3 s)")
    d.add_argument("--tracking", choices=("exact", "bicycle"), default="exact", help="tracking model (default exact)")
    d.add_argument("--replan", choices=("periodic", "lazy"), default="periodic",
                   help="re-plan every --replan-every steps (periodic), or only when the installed plan is short, "
                        "abnormal or in conflict (lazy)")
    d.add_argument("--max-steps", type=ca.positive_int, default=None, help="step cap of a drive (default 200 = 20 s)")
    d.add_argument("--animate", action="store_true", help="also write a GIF per drive")
    d.add_argument("--quick", action="store_true", help="fewer built-in scenes")
    d.add_argument("--seed", type=ca.nonnegative_int, default=0, help="seed of the built-in scenes")
    d.add_argument("--weights", help="cost weights JSON (jaxplan tune) for the planners that take them")


def _fail(msg: str) -> int:
    print(f"jaxplan drive: error: {msg}", file=sys.stderr)
    return 2


def run(args) -> int:
    from jaxplan.planner import get_factory, loadable_planners
    from jaxplan.scenarios.files import expand_paths
    from jaxplan.sim.drive import DEFAULT_MAX_STEPS, drive, n_steps_for

    if not args.paths and not args.builtin:
        return _fail("give scenario files or folders, or --builtin")
    names = loadable_planners() if args.planner == "all" else [p.strip() for p in args.planner.split(",") if p.strip()]
    if not names:
        return _fail("--planner: no planner named")
    for n in names:
        try:
            get_factory(n)
        except ValueError as e:
            return _fail(f"--planner: {e}")
    try:
        files = expand_paths(args.paths)
    except ValueError as e:
        return _fail(str(e))
    options = {}
    if args.weights:
        from jaxplan.tuning.lattice_tuning import WEIGHT_NAMES
        from jaxplan.tuning.train import load_weights

        try:  # the lattice's weight names only (the planners with weights take CostWeights)
            w = load_weights(args.weights, allowed=WEIGHT_NAMES, planner="lattice")
        except (OSError, ValueError) as e:
            return _fail(f"--weights {args.weights}: {e}")
        options = {n: {"weights": tuple(sorted(w.items()))} for n in names if "weights" in _fields(get_factory(n))}
    from jaxplan.scenarios.loader import ScenarioError
    from jaxplan.scenarios.scene import load_records, unique_names

    records, skipped = [], []
    for f in files:
        try:
            records += load_records([f])
        except (ScenarioError, ValueError, ImportError) as e:
            if f in args.paths:  # a file named on the command line must load
                return _fail(str(e))
            print(f"jaxplan drive: skipped {e}", file=sys.stderr)
            skipped.append(f)
    if args.builtin:
        from jaxplan.scenarios.builtin import builtin_records

        records += builtin_records(quick=args.quick, seed=args.seed)
    if not records:
        return _fail("no scenario could be loaded")
    records = unique_names(records)
    from jaxplan.sim.rollout import SimConfig

    cap = args.max_steps or DEFAULT_MAX_STEPS
    config = SimConfig(n_steps=n_steps_for(records, 0.1, cap), replan_every=args.replan_every, tracking=args.tracking,
                       replan=args.replan)
    res = drive(records, names, args.out, config, animate=args.animate, planner_options=options, skipped=skipped)
    from jaxplan.sim.report import headline_table

    print("\n".join(headline_table(res.summary)))
    print(f"wrote {args.out}/metrics.json, {args.out}/report.md and one folder per drive")
    return 0


def _fields(factory) -> set:
    import dataclasses

    return {f.name for f in dataclasses.fields(factory)} if dataclasses.is_dataclass(factory) else set()
