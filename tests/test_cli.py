import json
import os

from jaxplan.cli import main


def test_eval_geometry_writes_metrics_and_plot(tmp_path):
    out = str(tmp_path / "res")
    assert main(["eval", "geometry", "--quick", "--n", "300", "--out", out]) == 0
    m = json.load(open(os.path.join(out, "metrics.json")))
    assert m["geometry.pairs"] == 300
    assert m["geometry.overlap_agreement"] > 0.99
    assert m["geometry.area_rel_err_max_f32"] < 1e-3
    assert os.path.exists(os.path.join(out, "geometry.png"))


def test_unknown_suite_is_an_error(tmp_path, capsys):
    assert main(["eval", "nope", "--out", str(tmp_path)]) == 2
    assert "unknown suite" in capsys.readouterr().err


def test_report_lists_figures_and_plots(tmp_path):
    out = str(tmp_path / "res")
    assert main(["eval", "geometry", "--quick", "--n", "200", "--out", out]) == 0
    open(os.path.join(out, "zz_extra.png"), "wb").close()  # a plot the run did not write
    assert main(["report", out]) == 0
    text = open(os.path.join(out, "report.md")).read()
    assert "## geometry" in text and "overlap_agreement" in text and "![geometry.png](geometry.png)" in text
    assert "zz_extra.png" not in text  # only the plots recorded in the run's run.json
    assert main(["report", out]) == 0  # its own report: replaced
    assert main(["report", str(tmp_path / "missing")]) == 2


def test_tune_writes_a_model_that_eval_reads(tmp_path):
    from jaxplan.eval.lattice_suite import imitation_figures
    from jaxplan.eval.registry import SuiteArgs
    from jaxplan.tuning.imitation import ImitationModel

    path = str(tmp_path / "w.json")
    assert main(["tune", "lattice", "--steps", "3", "--out", path]) == 0
    model = ImitationModel.load(path)
    assert abs(sum(v * v for v in model.weights().values()) - 1.0) < 1e-5 and model.temperature > 0
    meta = json.load(open(path))["meta"]
    assert meta["planner"] == "lattice" and meta["source"] == "synthetic" and "weights.ade3" in meta["heldout"]
    m = imitation_figures(SuiteArgs(out=str(tmp_path), weights=path, n=32))  # the compiled shape of the others
    assert m["imitation.recorded"] == 0
    for k in ("default", "weights", "constant_velocity", "idm"):
        for f in ("ade3", "fde3", "ade5", "collision_share"):
            assert m[f"imitation.{k}.{f}"] >= 0
        assert m[f"imitation.{k}.ade3_ci_lo"] <= m[f"imitation.{k}.ade3"] <= m[f"imitation.{k}.ade3_ci_hi"]
    assert os.path.exists(os.path.join(str(tmp_path), "lattice_imitation.png"))
    # beside it the rule weights the closed-loop planner takes: drive reads them, and refuses the model
    from jaxplan.tuning.lattice_tuning import WEIGHT_NAMES
    from jaxplan.tuning.train import load_weights

    rule = str(tmp_path / "w.rule.json")
    assert set(load_weights(rule, allowed=WEIGHT_NAMES, planner="lattice")) == set(WEIGHT_NAMES)
    assert main(["drive", "--builtin", "--planner", "lattice", "--weights", path, "--out", str(tmp_path / "d")]) == 2
    assert main(["tune", "lattice", "--steps", "-3", "--out", path]) == 2
