"""Issue 13, items 11-13: the command line (each test failed on the code before the fix).

11 every bad argument gets one line naming it and exit status 2, before any heavy work
(the commands' work is replaced by stubs that fail the test if reached); 12 files that fail
to load are named and counted the same way in every suite; 13 ``--version`` and the suite
list in ``jaxplan eval --help``. The hypothesis fuzzing of the loader
(``test_robustness.py``) is extended to these arguments.
"""
import json
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan.cli import main
from test_loader import _minimal


class Reached(Exception):
    """A command got past the argument checks."""


def _stub_work(mp, calls):
    """Replace the commands' heavy work: record the call and stop."""
    import jaxplan.eval.registry as registry
    import jaxplan.eval.report as report
    import jaxplan.tuning.run as run

    def record(name):
        def f(*a, **k):
            calls.append((name, a, k))
            raise Reached(name)
        return f

    mp.setattr(registry, "run_suite", record("eval"))
    mp.setattr(run, "demonstrations", record("tune"))
    mp.setattr(report, "write_report", record("report"))


@pytest.fixture(scope="module")
def paths(tmp_path_factory):
    """Folders and files the arguments point at."""
    root = tmp_path_factory.mktemp("cli")
    good = root / "good"
    good.mkdir()
    (good / "a.json").write_text(json.dumps(_minimal()))
    (good / "broken.json").write_text("{")
    junk = root / "junk"
    junk.mkdir()
    (junk / "x.json").write_text("[1, 2]")
    (junk / "y.json").write_text("not json")
    empty = root / "empty"
    empty.mkdir()
    nojson = root / "nojson"
    nojson.mkdir()
    (nojson / "notes.txt").write_text("hello")
    xml = root / "xmlonly"
    xml.mkdir()
    from jaxplan.scenarios.commonroad import write_commonroad  # commonroad-io: a test dependency

    timed = _minimal()
    timed["planning_problems"][0]["goals"][0]["time"] = [0.0, 10.0]  # CommonRoad goals need a time interval
    write_commonroad(timed, str(xml / "s.xml"))  # a CommonRoad XML scenario the library wrote
    afile = root / "afile.txt"
    afile.write_text("x")
    weights = root / "w.json"
    weights.write_text(json.dumps({"weights": {"alpha": 1.0, "beta": 20.0}, "meta": {"planner": "lattice"}}))
    typo = root / "typo.json"
    typo.write_text(json.dumps({"weights": {"alhpa": 1.0}}))
    return {"good": str(good), "junk": str(junk), "empty": str(empty), "nojson": str(nojson), "file": str(afile),
            "missing": str(root / "missing"), "weights": str(weights), "typo": str(typo), "root": str(root),
            "under_file": str(afile / "sub"), "xml": str(xml)}


BAD = [  # (argv, words the one error line must contain)
    (["eval", "lattice", "--scenarios", "{missing}"], ["--scenarios", "{missing}", "no such folder"]),
    (["eval", "lattice", "--scenarios", "{empty}"], ["--scenarios", "{empty}", "no scenario files"]),
    (["eval", "lattice", "--scenarios", "{nojson}"], ["--scenarios", "no scenario files"]),
    (["eval", "lattice", "--scenarios", "{junk}"], ["--scenarios", "{junk}", "none of its 2 scenario files"]),
    (["eval", "lattice", "--scenarios", "{file}"], ["--scenarios", "{file}", "is a file"]),
    (["eval", "speed", "--scenarios", "{good},{missing}"], ["--scenarios", "{missing}", "no such folder"]),
    (["eval", "speed", "--scenarios", "{xml},{junk}"], ["--scenarios", "{junk}", "none of its 2 scenario files"]),
    (["eval", "lattice", "--n", "-1"], ["--n", "positive integer", "-1"]),
    (["eval", "lattice", "--n", "0"], ["--n", "positive integer", "0"]),
    (["eval", "lattice", "--n", "three"], ["--n", "three"]),
    (["eval", "lattice", "--seed", "-2"], ["--seed", "-2"]),
    (["eval", "lattice", "--out", "{file}"], ["--out", "{file}", "is a file"]),
    (["eval", "lattice", "--out", "{under_file}"], ["--out", "is a file"]),
    (["eval", "lattice", "--weights", "{missing}"], ["--weights", "{missing}", "no such file"]),
    (["eval", "lattice", "--weights", "{root}"], ["--weights", "is a folder"]),
    (["eval", "lattice", "--weights", "{typo}"], ["--weights", "'alhpa'", "allowed: alpha, beta"]),
    (["eval", "nope"], ["suite", "unknown suite 'nope'", "lattice"]),
    (["eval", "lattice,nope"], ["unknown suite 'nope'"]),
    (["tune", "lattice", "--steps", "-3"], ["--steps", "-3"]),
    (["tune", "lattice", "--steps", "0"], ["--steps", "0"]),
    (["tune", "lattice", "--out", "{root}"], ["--out", "{root}", "is a folder"]),
    (["tune", "lattice", "--scenarios", "{missing}"], ["--scenarios", "no such file or folder"]),
    (["tune", "boat"], ["planner", "boat"]),
    (["tune", "lattice", "--batch", "3"], ["--batch", "only with --closed-loop"]),
    (["tune", "lattice", "--lr", "0.02"], ["--lr", "only with --closed-loop"]),
    (["tune", "lattice", "--closed-loop", "--scenarios", "{root}", "--lr", "0"], ["--lr", "0"]),
    (["tune", "idm"], ["tune idm", "only with --closed-loop"]),
    (["tune", "lattice", "--closed-loop"], ["--closed-loop", "--scenarios"]),
    (["drive", "--builtin", "--out", "{root}/d", "--weights", "{missing}"],
     ["--weights", "{missing}", "no such file", "'handset'"]),
    (["drive", "--builtin", "--out", "{root}/d", "--weights", "hand-set"], ["--weights", "hand-set", "'handset'"]),
    (["report", "{missing}"], ["results_dir", "{missing}", "no such folder"]),
    (["report", "{file}"], ["results_dir", "is a file"]),
    (["eval"], ["suite"]),
    ([], ["cmd"]),
]


@pytest.mark.parametrize("argv,words", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_bad_argument_one_line_status_2_before_any_work(argv, words, paths, monkeypatch, capsys):
    calls = []
    _stub_work(monkeypatch, calls)
    argv = [a.format(**paths) for a in argv]
    assert main(argv) == 2
    out = capsys.readouterr()
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxplan: error: "), out.err
    for w in words:
        assert w.format(**paths) in lines[0]
    assert not calls and not out.out


def test_good_arguments_reach_the_work(paths, monkeypatch):
    calls = []
    _stub_work(monkeypatch, calls)
    with pytest.raises(Reached):
        main(["eval", "lattice", "--scenarios", paths["good"], "--n", "3", "--weights", paths["weights"],
              "--out", os.path.join(paths["root"], "new", "out")])
    name, (suite, args), _ = calls[-1]
    assert (name, suite, args.n, args.scenarios) == ("eval", "lattice", 3, paths["good"])
    both = f"{paths['good']},{paths['xml']}"  # several folders, one of CommonRoad XML
    with pytest.raises(Reached):
        main(["eval", "speed", "--scenarios", both, "--out", os.path.join(paths["root"], "new", "out2")])
    assert calls[-1][1][1].scenarios == both
    with pytest.raises(Reached):
        main(["tune", "speed", "--steps", "2", "--scenarios", paths["good"], "--out", paths["root"] + "/w2.json"])
    assert calls[-1][0] == "tune"


def test_drive_weights_handset_drives_every_planners_built_in_weights(paths, monkeypatch):
    """``jaxplan drive --weights handset``: the library's ``load_weights`` reads the name as no weights
    (``{}``: ``init_params`` keeps every planner's defaults), and the command hands every planner driven
    empty params and records the name with the run (drives stubbed: nothing is driven)."""
    import jax
    import numpy as np

    import jaxplan.sim.drive as drive_mod
    from jaxplan import cli_args
    from jaxplan.planner import make_planner
    from jaxplan.tuning.train import HANDSET, load_weights

    assert HANDSET == cli_args.HANDSET == "handset"
    for name in ("lattice", "idm", "brake"):
        assert load_weights(HANDSET, planner=name) == {}
        planner = make_planner(name)
        same = jax.tree_util.tree_map(lambda a, b: bool(np.array_equal(a, b)), planner.init_params({}),
                                      planner.init_params())
        assert all(jax.tree_util.tree_leaves(same))
    calls = []

    def stub(*a, **k):
        calls.append(k)
        raise Reached("drive")

    monkeypatch.setattr(drive_mod, "drive", stub)
    with pytest.raises(Reached):
        main(["drive", os.path.join(paths["good"], "a.json"), "--planner", "lattice,idm,brake", "--weights", "handset",
              "--out", os.path.join(paths["root"], "handset"), "--no-cache", "--workers", "1"])
    assert calls[-1]["planner_params"] == {"lattice": {}, "idm": {}, "brake": {}}
    assert calls[-1]["run_info"]["weights"] == "handset"


def test_missing_scenario_file_or_folder_given_as_file(paths):
    from jaxplan.scenarios.loader import ScenarioError, load_scenario

    with pytest.raises(ScenarioError, match="missing: no such file"):
        load_scenario(paths["missing"])
    with pytest.raises(ScenarioError, match="is a folder, not a scenario file"):
        load_scenario(paths["good"])
    from jaxplan import cli_args  # the type the subcommands that take a scenario file use

    for bad, words in ((paths["missing"], "no such file"), (paths["good"], "is a folder"),
                       (paths["file"], "not a scenario file")):
        with pytest.raises(cli_args.BadArgument, match=words):
            cli_args.scenario_file(bad)
    assert cli_args.scenario_file(os.path.join(paths["good"], "a.json")).endswith("a.json")


def test_suite_args_are_checked_at_the_api_too(paths):
    from jaxplan.eval.registry import SuiteArgs, run_suite

    for kw, field in ((dict(n=0), "SuiteArgs.n"), (dict(n=-1), "SuiteArgs.n"), (dict(out=paths["file"]), "SuiteArgs.out"),
                      (dict(scenarios=paths["missing"]), "SuiteArgs.scenarios")):
        with pytest.raises(ValueError, match=field):
            run_suite("geometry", SuiteArgs(**{"out": os.path.join(paths["root"], "api"), **kw}))


# ---------------------------------------------------------------------------- fuzzing

PATHS = ["{good}", "{junk}", "{empty}", "{nojson}", "{file}", "{missing}", "{root}", "{weights}", "{typo}",
         "{under_file}", ""]
INTS = st.one_of(st.integers(-10, 10).map(str), st.sampled_from(["", "1e3", "x", "-0", "007", " 3", "99999999999"]))
OPTIONS = {
    "eval": {"--scenarios": st.sampled_from(PATHS), "--out": st.sampled_from(PATHS), "--n": INTS, "--seed": INTS,
             "--weights": st.sampled_from(PATHS), "--quick": None},
    "tune": {"--scenarios": st.sampled_from(PATHS), "--out": st.sampled_from(PATHS), "--steps": INTS,
             "--seed": INTS},
    "report": {"--force": None},
}


@st.composite
def command_lines(draw):
    cmd = draw(st.sampled_from(sorted(OPTIONS)))
    argv = [cmd]
    if cmd == "eval":
        argv.append(draw(st.sampled_from(["lattice", "tune", "all", "nope", "geometry,lattice", ""])))
    elif cmd == "tune":
        argv.append(draw(st.sampled_from(["lattice", "speed", "other"])))
    else:
        argv.append(draw(st.sampled_from(PATHS)))
    opts = OPTIONS[cmd]
    for name in draw(st.lists(st.sampled_from(sorted(opts)), max_size=4, unique=True)):
        argv.append(name)
        if opts[name] is not None:
            argv.append(draw(opts[name]))
    return argv


def _valid_dir(p):
    return os.path.isdir(p) and any(f.endswith(".json") for f in os.listdir(p))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(argv=command_lines())
def test_fuzzed_command_lines_fail_clearly_or_reach_the_work_with_good_values(argv, paths, capsys):
    argv = [a.format(**paths) for a in argv]
    calls = []
    with pytest.MonkeyPatch.context() as mp:
        _stub_work(mp, calls)
        capsys.readouterr()
        try:
            rc = main(argv)
        except Reached:
            rc = None
        out = capsys.readouterr()
    if rc is not None:  # refused: one line, status 2, nothing run
        assert rc == 2 and not calls, (argv, out)
        lines = out.err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("jaxplan: error: "), (argv, out.err)
        return
    name, a, _ = calls[-1]  # reached the work: every value it gets is a good one
    args = a[1] if name == "eval" else None
    if name == "eval":
        assert args.n is None or args.n >= 1
        assert args.seed >= 0 and (not os.path.exists(args.out) or os.path.isdir(args.out))
        assert args.scenarios is None or args.scenarios in (paths["good"], paths["root"])  # root: good/ inside
        assert args.weights is None or args.weights == paths["weights"]
    elif name == "tune":
        assert a[0] is None or a[0].directory in (paths["good"], paths["root"])  # a loaded folder, skipped counted
    else:
        assert os.path.isdir(a[0])


# --------------------------------------------------------------- skipped files


def test_skipped_files_are_named_and_counted_by_one_helper(paths, monkeypatch, capsys):
    import io

    from jaxplan.scenarios import files

    err = io.StringIO()
    folder = files.load_folder(paths["good"], stderr=err)
    assert len(folder) == 1 and [os.path.basename(f) for f, _ in folder.skipped] == ["broken.json"]
    assert "broken.json: not valid JSON" in err.getvalue()
    with pytest.raises(files.ScenarioError, match="none of its 2 scenario files could be loaded"):
        files.load_folder(paths["junk"], stderr=err)

    # every suite that reads --scenarios goes through it
    class Used(Exception):
        pass

    def spy(directory, *a, **k):
        raise Used(directory)

    monkeypatch.setattr(files, "load_folder", spy)
    from jaxplan.eval.lattice_suite import run_recorded
    from jaxplan.eval.registry import SuiteArgs
    from jaxplan.eval.speed_suite import recorded_scenes
    from jaxplan.eval.tune_suite import tune_suite
    from jaxplan.tuning.run import demonstrations

    for call in (lambda: run_recorded(paths["good"], 8, 4), lambda: recorded_scenes(paths["good"]),
                 lambda: tune_suite(SuiteArgs(out=paths["root"], scenarios=paths["good"])),
                 lambda: demonstrations(paths["good"])):
        with pytest.raises(Used, match="good"):
            call()
    monkeypatch.undo()
    # and the speed suite's recorded scenes report the count it gives
    d = _minimal()
    d["obstacles"][0]["states"] = [[0.1 * k, 20.0 + k, 0.0, 0.0, 10.0, 0.0] for k in range(60)]  # as in test_inputs
    folder = os.path.join(paths["root"], "speed")
    os.makedirs(folder)
    with open(os.path.join(folder, "a.json"), "w") as f:
        json.dump(d, f)
    with open(os.path.join(folder, "b.json"), "w") as f:
        f.write("{")
    capsys.readouterr()
    recs, skipped = recorded_scenes(folder)
    assert skipped == 1 and len(recs) == 1 and "b.json" in capsys.readouterr().err


# ---------------------------------------------------------- version and suites


def test_version_and_suite_list(capsys):
    import jaxplan

    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"jaxplan {jaxplan.__version__}"
    assert main(["eval", "--help"]) == 0
    text = capsys.readouterr().out
    listed = text.split("suites:\n", 1)[1].splitlines()
    names = [ln.split()[0] for ln in listed if ln.strip()]
    from jaxplan.eval.registry import SUITES, load_builtin_suites

    load_builtin_suites()  # the suites that register themselves when imported: the same list
    assert names == sorted(SUITES) and {"lattice", "speed", "tune"} <= set(names)
    assert all(len(ln.split(None, 1)) == 2 for ln in listed if ln.strip())  # a line of text each
    assert any("candidate lattice" in ln for ln in listed)
