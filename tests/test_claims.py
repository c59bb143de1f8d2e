"""The claims table: values, verdicts, ratios, figures a run did not measure, and its place in the report."""
import json
import os
import re

import pytest

from jaxplan.eval.claims import CLAIMS, Claim, claims_table, judge, met, value


def test_values_verdicts_and_missing_figures():
    claims = (Claim("s", "a", "x.a", "<=", 1.0), Claim("s", "b", "x.b / x.c", ">=", 2.0),
              Claim("s", "c", "x.d", "==", 0), Claim("s", "d", "x.missing", "<=", 1.0),
              Claim("s", "e", "x.a / x.zero", "<=", 1.0), Claim("s", "f", "x.nan", "<=", 1.0))
    m = {"x.a": 1.5, "x.b": 3.0, "x.c": 1.0, "x.d": 0, "x.zero": 0.0, "x.nan": float("nan")}
    rows = judge(m, claims)
    assert [(v, ok) for _, v, ok in rows] == [(1.5, False), (3.0, True), (0.0, True), (None, None), (None, None),
                                              (None, None)]
    lines = claims_table(m, claims)
    assert len(lines) == 2 + len(claims) and "**no**" in lines[2] and "not measured in this run" in lines[5]
    assert met(1.0, "<=", 1.0) and not met(1.0 + 1e-6, "==", 1.0)
    with pytest.raises(ValueError, match="op"):
        met(1.0, "<", 2.0)
    assert value({"k": True}, "k") is None  # a flag is not a figure


def test_every_claim_key_is_written_by_its_suite():
    """Keys named ``<suite>.claim.<name>`` match a key the suite's source writes (literal or f-string
    template): catches renames."""
    root = os.path.join(os.path.dirname(__file__), "..", "jaxplan", "eval")
    checked = 0
    for c in CLAIMS:
        for key in c.figure.split(" / "):
            suite, _, rest = key.partition(".")
            if not rest.startswith("claim."):
                continue
            with open(os.path.join(root, f"{suite}_suite.py")) as f:
                templates = re.findall(r'"(claim\.[^"]*)"', f.read())
            pats = [re.escape(t).replace(r"\{", "{").replace(r"\}", "}") for t in templates]
            pats = [re.sub(r"\{[^}]*\}", r"[^.]+", p) for p in pats]
            assert any(re.fullmatch(p, rest) for p in pats), key
            checked += 1
    assert checked >= 5


def test_report_opens_with_the_claims(tmp_path):
    from jaxplan.eval.report import write_report

    (tmp_path / "metrics.json").write_text(json.dumps({"parkout.claim.grid_runs_with_collision": 0, "tiny.n": 1}))
    text = open(write_report(str(tmp_path))).read()
    assert text.index("## Claims") < text.index("## tiny")
    assert "| park-out | grid park-out never collides | `parkout.claim.grid_runs_with_collision` | 0 | == 0 | yes |" in text
