"""Plan, drive and judge: ``jaxplan drive``, ``eval``, ``tune``, ``report``, ``parkout`` (also ``python -m jaxplan``).

``jaxplan drive PATHS``, ``jaxplan eval SUITE``, ``jaxplan tune PLANNER``, ``jaxplan report DIR``,
``jaxplan parkout SCENE``.

Every argument is checked before any heavy work (``jaxplan.cli_args``); a bad one gets one
line ``jaxplan: error: ...`` naming it, and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from jaxplan import cli_args as ca


def _suites_epilog() -> str:
    from jaxplan.eval.registry import suite_summaries

    rows = suite_summaries()
    w = max(map(len, rows), default=0)
    return "suites:\n" + "\n".join(f"  {n.ljust(w)}  {line}" for n, line in rows.items())


def _suite_spec(text: str) -> str:
    from jaxplan.eval.registry import suite_names

    try:
        suite_names(text)
    except ValueError as e:
        raise ca.BadArgument(str(e)) from None
    return text


def parser() -> argparse.ArgumentParser:
    from jaxplan import __version__

    p = ca.ArgumentParser(prog="jaxplan", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"jaxplan {__version__}")
    sub = p.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser(
        "eval",
        help="run an evaluation suite and write OUT/metrics.json and plots",
        epilog=_suites_epilog(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    e.add_argument("suite", type=_suite_spec, help="suite name (below), several joined by commas, or 'all'")
    e.add_argument(
        "--scenarios",
        type=ca.scenario_dirs,
        help="folder of scenario JSON files (shared format); the speed suite takes several, "
        "comma-separated, and CommonRoad XML folders",
    )
    e.add_argument(
        "--out",
        type=ca.output_dir,
        default="results",
        help="output directory (default: results); a run replaces the metrics of an earlier run there",
    )
    e.add_argument("--n", type=ca.positive_int, help="number of scenes / cases")
    e.add_argument("--seed", type=ca.nonnegative_int, default=0)
    e.add_argument("--quick", action="store_true", help="small sizes, for a demo or a smoke test")
    e.add_argument(
        "--weights",
        type=ca.weights_file("lattice"),
        help="cost weights JSON written by `jaxplan tune lattice` (suites that use them)",
    )
    t = sub.add_parser(
        "tune",
        help="learn cost weights from demonstrations, or by gradient through closed-loop "
        "drives (--closed-loop), and write them as JSON",
    )
    t.add_argument("planner", choices=("lattice", "speed", "idm"))
    t.add_argument(
        "--scenarios",
        type=ca.existing_path,
        help="directory of recorded scenarios (default: synthetic demonstrations); with --closed-loop, "
        "scenario files or a folder of any format `drive` reads",
    )
    t.add_argument(
        "--closed-loop",
        action="store_true",
        help="tune by gradient (optax) through closed-loop drives of --scenarios, split by location, with "
        "random search and CMA-ES in the same number of drives (lattice, idm)",
    )
    t.add_argument("--scenes", type=ca.positive_int, help="--closed-loop: scenes sampled (default 24)")
    t.add_argument(
        "--drive-steps", type=ca.positive_int, help="--closed-loop: steps of each drive, 0.1 s each (default 80)"
    )
    t.add_argument("--batch", type=ca.positive_int, help="--closed-loop: training scenes per step (default 8)")
    t.add_argument(
        "--temperature",
        type=ca.positive_float,
        help="--closed-loop: the lattice's soft-selection temperature (cost units, default 1)",
    )
    t.add_argument("--lr", type=ca.positive_float, help="--closed-loop: Adam's step on the log-weights (default 0.1)")
    t.add_argument(
        "--out", type=ca.output_file, default="weights.json", help="weights file to write (default: weights.json)"
    )
    t.add_argument(
        "--steps",
        type=ca.positive_int,
        help="optimiser steps (default: 800 lattice on recorded scenarios, 400 synthetic; 40 speed; "
        "20 with --closed-loop)",
    )
    t.add_argument("--seed", type=ca.nonnegative_int, default=0)
    r = sub.add_parser("report", help="write RESULTS_DIR/report.md from its metrics and plots")
    r.add_argument("results_dir", type=ca.existing_dir)
    r.add_argument("--force", action="store_true", help="replace a report.md that `jaxplan report` did not write")
    from jaxplan.sim import cli as drive_cli

    drive_cli.add_parser(sub)
    from jaxplan.parking import cli as parkout_cli

    parkout_cli.add_parser(sub)
    return p


def main(argv=None) -> int:
    args, status = ca.parse(parser(), argv)
    if args is None:
        return status
    import matplotlib

    matplotlib.use("Agg")  # the command only writes picture files; library calls keep the user's backend
    if args.cmd != "report":  # every other command compiles: with XLA CPU's loop emitters
        from jaxplan.compile_options import use_fast_compile

        use_fast_compile()
    if args.cmd == "drive":
        from jaxplan.sim import cli as drive_cli

        return drive_cli.run(args)
    if args.cmd == "parkout":
        from jaxplan.parking import cli as parkout_cli

        return parkout_cli.run(args)
    try:
        if args.cmd == "report":
            from jaxplan.eval.report import write_report

            print(f"wrote {write_report(args.results_dir, force=args.force)}")
            return 0
        if args.cmd == "tune":
            return _tune(args)
        if args.cmd == "eval":
            from jaxplan.eval.registry import SuiteArgs, run_suite

            m = run_suite(
                args.suite,
                SuiteArgs(
                    out=args.out,
                    n=args.n,
                    seed=args.seed,
                    quick=args.quick,
                    scenarios=args.scenarios,
                    weights=args.weights,
                ),
            )
            json.dump(m, sys.stdout, indent=1, sort_keys=True)
            print(f"\nwrote {args.out}/metrics.json")
    except ValueError as err:
        print(f"jaxplan: error: {err}", file=sys.stderr)
        return 2
    return 0


def _tune(args) -> int:
    import dataclasses

    if args.closed_loop:
        if not args.scenarios:
            raise ValueError("--closed-loop: give --scenarios (files or a folder of them)")
        from jaxplan.tuning.closed_loop import tune_files

        given = {
            k: getattr(args, k)
            for k in ("scenes", "drive_steps", "steps", "batch", "lr", "temperature")
            if getattr(args, k) is not None
        }  # the rest: tune_files' defaults
        figures = tune_files([args.scenarios], args.planner, args.out, seed=args.seed, **given)
        json.dump(figures, sys.stdout, indent=1, sort_keys=True)
        print(
            f"\nwrote {args.out} (`jaxplan drive --weights {args.out}` drives them) and "
            f"{os.path.splitext(args.out)[0]}.png"
        )
        return 0
    if args.planner == "idm":
        raise ValueError("tune idm: only with --closed-loop (demonstrations tune lattice and speed)")
    closed_only = [
        f"--{k.replace('_', '-')}"
        for k in ("scenes", "drive_steps", "batch", "lr", "temperature")
        if getattr(args, k) is not None
    ]
    if closed_only:
        raise ValueError(f"{', '.join(closed_only)}: only with --closed-loop")
    if args.scenarios:
        ca.scenario_dir(args.scenarios)

    from jaxplan.tuning.baselines import IDM_GRID
    from jaxplan.tuning.run import (
        RECORDED_LR,
        RECORDED_STEPS,
        SMALL_IDM_GRID,
        compare_lattice,
        demonstrations,
        tune_speed,
    )
    from jaxplan.weights import save_weights

    folder = None
    if args.scenarios:
        from jaxplan.scenarios.files import load_folder

        folder = load_folder(args.scenarios)
    train, val, source = demonstrations(folder, seed=args.seed)
    if args.planner == "lattice":
        recorded = source == "recorded"
        res = compare_lattice(
            train,
            val,
            steps=args.steps or (RECORDED_STEPS if recorded else 400),
            lr=RECORDED_LR if recorded else 0.05,
            seed=args.seed,
            candidate_set="rich" if recorded else "small",
            idm_grid=IDM_GRID if recorded else SMALL_IDM_GRID,
            ce_weight=0.0 if recorded else 1.0,
        )
        model = dataclasses.replace(
            res.model, meta={**res.model.meta, "planner": "lattice", "source": source, "heldout": res.metrics}
        )
        model.save(args.out)
        metrics = res.metrics
        rule = os.path.splitext(args.out)[0] + ".rule.json"
        save_weights(
            rule,
            res.rule,
            meta={
                "planner": "lattice",
                "source": source,
                "fit": "grid over beta, delta",
                "heldout.grid.ade3": res.metrics.get("grid.ade3"),
            },
        )
        print(f"wrote {rule} (the rule weights fit by grid: `jaxplan drive --weights` drives them)", file=sys.stderr)
    else:
        res = tune_speed(train, val, steps=args.steps or 40, seed=args.seed)
        metrics = res.metrics
        save_weights(args.out, res.weights, meta={"planner": args.planner, "source": source, **res.metrics})
    if folder is not None:
        metrics = {**metrics, "skipped_files": len(folder.skipped)}
    json.dump(metrics, sys.stdout, indent=1, sort_keys=True)
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
