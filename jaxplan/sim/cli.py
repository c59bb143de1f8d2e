"""``jaxplan drive PATHS... --planner NAME --out DIR``: closed-loop drives (see ``jaxplan.sim.drive``).

Any number of scenario files or folders (searched recursively): shared JSON and CommonRoad XML,
either gzip-compressed. Parsed scenes are cached on disk and compiled programs too (JAX's
persistent compilation cache), both under ``$JAXPLAN_CACHE_DIR`` (default ``~/.cache/jaxplan``);
``--no-cache`` uses neither. A run into a folder that holds the same run resumes it.
"""

from __future__ import annotations

import sys
from typing import Any

from jaxplan import cli_args as ca


def add_parser(sub) -> None:
    d = sub.add_parser(
        "drive",
        help="drive scenarios in closed loop with a planner; write drives, metrics, report",
        description=__doc__,
    )
    d.add_argument(
        "paths",
        nargs="*",
        help="scenario files (.json shared format, .xml CommonRoad, either .gz) or "
        "folders of them (searched recursively)",
    )
    d.add_argument("--builtin", action="store_true", help="also drive the built-in synthetic scenes")
    d.add_argument(
        "--planner",
        default="lattice",
        help="planner name, several separated by commas, or 'all' (every planner that loads, "
        "the baselines brake and idm included); NAME:OPTION=VALUE sets an option of its config "
        "(e.g. pathspeed:nonblocking=false)",
    )
    d.add_argument(
        "--out",
        required=True,
        type=ca.output_dir,
        help="output folder (a run there with the same settings and files is resumed)",
    )
    d.add_argument("--replan-every", type=ca.positive_int, default=3, help="steps between re-plans (default 3 = 0.3 s)")
    d.add_argument("--tracking", choices=("exact", "bicycle"), default="exact", help="tracking model (default exact)")
    d.add_argument(
        "--replan",
        choices=("periodic", "lazy"),
        default="periodic",
        help="re-plan every --replan-every steps (periodic), or only when the installed plan is short, "
        "abnormal or in conflict (lazy)",
    )
    d.add_argument(
        "--agents",
        choices=("log", "idm"),
        default="log",
        help="traffic: replay the recording (log, default) or follow the recorded paths keeping an IDM "
        "gap to what is ahead, the car included (idm)",
    )
    d.add_argument(
        "--prediction",
        choices=("oracle", "cv"),
        default="oracle",
        help="what planners see of the traffic: the recorded future (oracle, default: CommonRoad's "
        "convention) or the present extrapolated at constant speed along each lane (cv)",
    )
    d.add_argument(
        "--max-steps",
        type=ca.positive_int,
        default=None,
        help="step cap of a drive (default 200 = 20 s); each scene is driven to the end of its goal's "
        "time window, at most this",
    )
    d.add_argument(
        "--sample",
        type=ca.positive_int,
        default=None,
        help="drive a seeded sample of this many files (stratified by folder; --seed)",
    )
    d.add_argument("--batch", type=ca.positive_int, default=None, help="scenes per batch (default 16)")
    d.add_argument(
        "--plots",
        choices=("auto", "all", "failed", "none"),
        default="auto",
        help="per-drive pictures: all, only the drives that did not succeed, none; auto (default): all up "
        "to 50 drives, else the failed ones",
    )
    d.add_argument("--animate", action="store_true", help="also write a GIF per drive")
    d.add_argument("--quick", action="store_true", help="fewer built-in scenes")
    d.add_argument("--seed", type=ca.nonnegative_int, default=0, help="seed of the built-in scenes and of --sample")
    d.add_argument(
        "--weights",
        type=ca.weights_file_or_handset,
        help="the planners' params: a weights JSON (jaxplan tune) every planner driven takes, or "
        "'handset': every planner's built-in, hand-set weights (to compare with a tuned file)",
    )
    d.add_argument("--fresh", action="store_true", help="discard an earlier run in --out instead of resuming it")
    d.add_argument(
        "--workers",
        type=ca.positive_int,
        default=None,
        help="processes that parse scenario files (default: the CPU count, at most 8)",
    )
    d.add_argument(
        "--no-cache", action="store_true", help="neither read nor write the scene cache and the compilation cache"
    )


def _fail(msg: str) -> int:
    print(f"jaxplan drive: error: {msg}", file=sys.stderr)
    return 2


def run(args) -> int:
    from jaxplan.planner import loadable_planners, make_planner, planner_spec
    from jaxplan.scenarios.files import expand_paths, sample_files
    from jaxplan.sim.drive import DEFAULT_BATCH, DEFAULT_MAX_STEPS, drive

    if not args.paths and not args.builtin:
        return _fail("give scenario files or folders, or --builtin")
    names = loadable_planners() if args.planner == "all" else [p.strip() for p in args.planner.split(",") if p.strip()]
    if not names:
        return _fail("--planner: no planner named")
    if len(set(names)) < len(names):
        return _fail("--planner: a planner named twice")
    for n in names:
        try:
            make_planner(n)
        except (ValueError, TypeError) as e:
            return _fail(f"--planner: {e}")
    try:
        files = expand_paths(args.paths)
    except ValueError as e:
        return _fail(str(e))
    if args.sample is not None:
        if not files:
            return _fail("--sample: give scenario files or folders to sample from")
        files = sample_files(files, args.sample, args.seed)
    options: dict[str, dict[str, Any]] = {}
    params: dict[str, Any] = {}
    if args.weights:
        from jaxplan.weights import load_weights

        for n in names:  # every planner takes them as its params, or the run is refused
            try:
                w = load_weights(args.weights, planner=planner_spec(n)[0])
                make_planner(n).init_params(w)
            except (OSError, ValueError, TypeError) as e:
                return _fail(f"--weights {args.weights}: planner {n}: {e}")
            params[n] = w
    from jaxplan.scenarios.cache import enable_compilation_cache, load_many
    from jaxplan.scenarios.files import unique_names
    from jaxplan.sim.drive import run_settings
    from jaxplan.sim.rollout import SimConfig
    from jaxplan.sim.store import RunMismatch, check_settings

    cap = args.max_steps or DEFAULT_MAX_STEPS
    config = SimConfig(
        n_steps=cap,
        replan_every=args.replan_every,
        tracking=args.tracking,
        replan=args.replan,
        agents=args.agents,
        prediction=args.prediction,
    )
    run_info = {
        "max_steps": cap,
        "builtin": bool(args.builtin),
        "quick": bool(args.quick),
        "seed": args.seed,
        "weights": args.weights and _digest(args.weights),
    }
    if not args.fresh:  # a run of other settings in --out: refused before any file is read
        try:
            check_settings(args.out, run_settings(names, config, options, run_info, params))
        except RunMismatch as e:
            return _fail(str(e))
    if not args.no_cache:
        enable_compilation_cache()
    loaded = load_many(files, workers=args.workers, use_cache=not args.no_cache, progress=True)
    named = set(args.paths)
    for path, reason in loaded.errors:
        if path in named:  # a file named on the command line must load
            return _fail(reason)
        print(f"jaxplan drive: skipped {reason}", file=sys.stderr)
    records = list(loaded.records)
    skipped = [p for p, _ in loaded.errors]
    if args.builtin:
        from jaxplan.scenarios.builtin import builtin_records

        records += builtin_records(quick=args.quick, seed=args.seed)
    if not records:
        return _fail("no scenario could be loaded")
    records = unique_names(records)
    try:
        res = drive(
            records,
            names,
            args.out,
            config,
            animate=args.animate,
            planner_options=options,
            planner_params=params,
            skipped=skipped,
            batch_size=args.batch or DEFAULT_BATCH,
            plots=args.plots,
            fresh=args.fresh,
            run_info=run_info,
            parse_s=loaded.parse_s,
        )
    except RunMismatch as e:
        return _fail(str(e))
    from jaxplan.sim.report import headline_table, timing_lines

    print("\n".join(headline_table(res.summary)))
    print("\n".join(timing_lines(res.timing)))
    print(f"wrote {args.out}/metrics.json, {args.out}/report.md and one folder per drive")
    return 0


def _digest(path: str) -> str:
    if path == ca.HANDSET:  # a name, not a file
        return path
    from jaxplan.scenarios.cache import file_digest

    return file_digest(path)[:16]
