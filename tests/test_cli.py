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


def test_tune_writes_weights_that_eval_reads(tmp_path):
    from jaxplan.eval.lattice_suite import imitation_figures
    from jaxplan.eval.registry import SuiteArgs
    from jaxplan.tuning.train import load_weights

    path = str(tmp_path / "w.json")
    assert main(["tune", "lattice", "--steps", "3", "--out", path]) == 0
    w = load_weights(path)
    assert set(w) >= {"alpha", "beta", "gamma", "delta"} and all(v > 0 for v in w.values())
    meta = json.load(open(path))["meta"]
    assert meta["planner"] == "lattice" and meta["source"] == "synthetic" and "after.ade3" in meta
    m = imitation_figures(SuiteArgs(out=str(tmp_path), weights=path, n=24))
    assert m["imitation.recorded"] == 0
    assert 0 <= m["imitation.weights.top1"] <= 1 and m["imitation.default.ade3"] >= 0
