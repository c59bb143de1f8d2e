"""Issue 13, items 9 and 10: runs that lose or mix nothing (each test failed on the code before the fix).

9 ``run_chunked`` resumes only the run its manifest records; 10 a results folder holds one
run: ``metrics.json`` replaced (never merged), unreadable files named, ``report.md`` never
overwritten unless ``jaxplan report`` wrote it, only the run's own plots shown.
"""
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.eval.batch import load_results, run_chunked


@jax.jit
def _double(batch):
    return {"y": 2.0 * batch["x"]}


@jax.jit
def _square(batch):
    return {"y": batch["x"] ** 2}


def _make(offset):
    def make(start, stop):
        return {"x": np.arange(start, stop, dtype=np.float32) + offset}

    return make


def test_resume_only_the_same_run(tmp_path):
    out = str(tmp_path / "run")
    kw = dict(progress=False, process_index=0, process_count=1)
    first = run_chunked(_double, _make(0), 10, out, chunk_size=4, **kw)
    assert first["chunks_run"] == 3
    same = run_chunked(_double, _make(0), 10, out, chunk_size=4, **kw)
    assert same == {**same, "chunks_run": 0, "chunks_skipped": 3}
    for change, words in (
            (dict(fn=_square), "the function"),                      # gave the first run's results
            (dict(chunk_size=3), "the chunk size (4 then, 3 now)"),  # gave 11 results for 10 scenes
            (dict(n_scenes=12), "the number of scenes"),
            (dict(make=_make(5)), "the chunk maker"),                # the same factory, another closure value
            (dict(inputs={"seed": 1}), "the inputs")):
        args = {**dict(fn=_double, make=_make(0), n_scenes=10, chunk_size=4), **change}
        extra = {"inputs": args["inputs"]} if "inputs" in args else {}
        with pytest.raises(ValueError) as e:
            run_chunked(args["fn"], args["make"], args["n_scenes"], out, chunk_size=args["chunk_size"], **extra, **kw)
        msg = str(e.value)
        assert words in msg and out in msg and "start fresh" in msg and "fresh=True" in msg
    np.testing.assert_array_equal(load_results(out)["y"], 2.0 * np.arange(10))
    again = run_chunked(_square, _make(0), 10, out, chunk_size=3, fresh=True, **kw)
    assert again["chunks_run"] == 4
    np.testing.assert_array_equal(load_results(out)["y"], np.arange(10.0) ** 2)


def test_chunks_without_a_manifest_are_refused(tmp_path):
    out = tmp_path / "old"
    out.mkdir()
    np.savez(out / "chunk_00000.npz", _start=np.int64(0), y=np.zeros(4))
    with pytest.raises(ValueError, match="no manifest.json"):
        run_chunked(_double, _make(0), 4, str(out), chunk_size=4, progress=False, process_index=0, process_count=1)


# --------------------------------------------------------- metrics and reports


@pytest.fixture
def tiny_suite(monkeypatch):
    """A registered suite that writes one plot and two figures (no JAX work)."""
    from jaxplan.eval import registry

    def tiny(args):
        """A tiny test suite."""
        with open(os.path.join(args.out, "tiny_plot.png"), "wb") as f:
            f.write(b"png")
        return {"figure": 1.5, "n": args.n or 3}

    registry.load_builtin_suites()
    monkeypatch.setitem(registry.SUITES, "tiny", tiny)
    return "tiny"


def test_metrics_replaced_never_merged(tmp_path, tiny_suite, capsys):
    from jaxplan.cli import main

    out = tmp_path / "res"
    out.mkdir()
    (out / "metrics.json").write_text('{"my.figure": 42}')
    (out / "stale.png").write_bytes(b"old")  # a plot from someone else
    assert main(["eval", tiny_suite, "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert "my.figure" not in m and m["tiny.figure"] == 1.5
    assert "replacing" in capsys.readouterr().err
    run = json.loads((out / "run.json").read_text())
    assert run["suites"] == ["tiny"] and run["outputs"] == ["tiny_plot.png"]
    # an unreadable metrics.json from an earlier run does not lose the finished run
    (out / "metrics.json").write_text("{not json")
    assert main(["eval", tiny_suite, "--out", str(out), "--n", "7"]) == 0
    assert json.loads((out / "metrics.json").read_text())["tiny.n"] == 7


def test_report_shows_the_run_and_keeps_foreign_reports(tmp_path, tiny_suite, capsys):
    from jaxplan.cli import main

    out = tmp_path / "res"
    assert main(["eval", tiny_suite, "--out", str(out)]) == 0
    (out / "zz_unrelated.png").write_bytes(b"x")
    (out / "report.md").write_text("my notes\n")  # not written by jaxplan report
    capsys.readouterr()
    assert main(["report", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(out / "report.md") in err and "--force" in err
    assert (out / "report.md").read_text() == "my notes\n"
    assert main(["report", str(out), "--force"]) == 0
    text = (out / "report.md").read_text()
    assert "![tiny_plot.png](tiny_plot.png)" in text and "zz_unrelated" not in text and "| figure | 1.5 |" in text
    assert main(["report", str(out)]) == 0  # its own, unedited: replaced
    (out / "report.md").write_text(text.replace("1.5", "9.9"))  # edited by hand
    assert main(["report", str(out)]) == 2
    (out / "metrics.json").write_text("{broken")
    assert main(["report", str(out), "--force"]) == 2
    assert str(out / "metrics.json") in capsys.readouterr().err
