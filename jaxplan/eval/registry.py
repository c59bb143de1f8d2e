"""Suites register themselves here; ``jaxplan eval SUITE`` runs them.

One run writes one results folder: ``OUT/metrics.json`` (a flat mapping of named
figures, ``<suite>.<figure>``) and ``OUT/run.json`` (what ran: the suites, their
arguments, and every file the run wrote, its plots included), both through a temporary
file and an atomic rename. A run **replaces** the ``metrics.json`` and ``run.json`` of an
earlier run in the same folder (it says so on stderr); it never merges into them, so the
folder's figures are always those of one run. To keep several runs, give each its own
``--out``; to run several suites in one run, name them together (``lattice,speed``) or
use ``all``.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import json
import numbers
import os
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

SUITES: dict[str, Callable] = {}
METRICS, RUN = "metrics.json", "run.json"


@dataclass(frozen=True)
class SuiteArgs:
    """What every suite receives from the CLI."""

    out: str
    n: int | None = None
    seed: int = 0
    quick: bool = False
    scenarios: str | None = None
    weights: str | None = None

    def validate(self) -> SuiteArgs:
        """Refuse bad values with a ``ValueError`` naming the field (the checks of ``jaxplan.cli_args``)."""
        from jaxplan import cli_args as ca

        checks: list[tuple[str, Callable[[Any], object], object]] = [("out", ca.output_dir, self.out)]
        if self.n is not None:
            checks.append(("n", ca.positive_int, self.n))
        checks.append(("seed", ca.nonnegative_int, self.seed))
        if self.scenarios is not None:
            checks.append(("scenarios", lambda v: [ca.existing_dir(p) for p in str(v).split(",") if p], self.scenarios))
        if self.weights is not None:
            checks.append(("weights", ca.existing_file, self.weights))
        for name, check, value in checks:
            if name in ("n", "seed") and (isinstance(value, bool) or not isinstance(value, numbers.Integral)):
                raise ValueError(f"SuiteArgs.{name}: must be an integer, got {value!r}")
            try:
                check(value)
            except ca.BadArgument as e:
                raise ValueError(f"SuiteArgs.{name}: {e}") from None
        return self


def register(name: str):
    """Decorator: ``fn(args: SuiteArgs) -> dict[str, float]`` becomes suite ``name``.

    ``jaxplan eval --help`` shows the first line of ``fn``'s docstring (or of its module's)."""

    def wrap(fn):
        SUITES[name] = fn
        return fn

    return wrap


def load_builtin_suites():
    """Import every ``jaxplan/eval/*_suite.py``; each registers itself."""
    import importlib
    import pkgutil

    import jaxplan.eval as pkg

    for mod in pkgutil.iter_modules(pkg.__path__):
        if mod.name.endswith("_suite"):
            importlib.import_module(f"jaxplan.eval.{mod.name}")


def _first_line(doc: str | None, name: str) -> str:
    """The first sentence of a docstring's first paragraph, on one line, without reST markup
    and without a leading ``Suite ``name``:``."""
    para = " ".join((doc or "").strip().split("\n\n")[0].split()).replace("``", "")
    for prefix in (f"Suite {name}:", f"Suite {name}"):
        if para.startswith(prefix):
            para = para[len(prefix) :].strip()
    end = para.find(". ")
    return para if end < 0 else para[: end + 1]


@functools.lru_cache(maxsize=64)
def _module_summaries(path: str, mtime_ns: int) -> dict[str, str]:
    """``{suite: line}`` of the ``@register`` functions of one suite module (parsed, not imported)."""
    with open(path) as f:
        tree = ast.parse(f.read())
    mod_doc = ast.get_docstring(tree)
    out: dict[str, str] = {}
    for node in tree.body:
        if not isinstance(node, ast.FunctionDef):
            continue
        for dec in node.decorator_list:
            if (
                isinstance(dec, ast.Call)
                and getattr(dec.func, "id", None) == "register"
                and dec.args
                and isinstance(dec.args[0], ast.Constant)
                and isinstance(dec.args[0].value, str)
            ):
                name = dec.args[0].value
                out[name] = _first_line(ast.get_docstring(node) or mod_doc, name)
    return out


def suite_summaries() -> dict[str, str]:
    """``{suite: one line}`` for every built-in suite, read from the suite modules' source
    (no import: ``jaxplan eval --help`` stays fast), plus suites registered at run time."""
    import jaxplan.eval as pkg

    out = {}
    folder = os.path.dirname(pkg.__file__)
    for fname in sorted(os.listdir(folder)):
        if fname.endswith("_suite.py"):
            path = os.path.join(folder, fname)
            out.update(_module_summaries(path, os.stat(path).st_mtime_ns))
    for name, fn in SUITES.items():
        if name not in out:
            out[name] = _first_line(fn.__doc__ or sys.modules.get(fn.__module__).__doc__, name)
    return dict(sorted(out.items()))


def suite_names(spec: str) -> list[str]:
    """Suites named by ``spec``: one name, ``all``, or several joined by commas."""
    known = suite_summaries()
    names = sorted(known) if spec == "all" else [s.strip() for s in str(spec).split(",") if s.strip()]
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise ValueError(
            f"unknown suite {unknown[0] if unknown else spec!r}; known: {', '.join(['all'] + sorted(known))}"
        )
    return list(dict.fromkeys(names))


def write_json_atomic(path: str, obj) -> None:
    """Write ``obj`` as JSON through a temporary file and an atomic rename."""
    tmp = f"{path}.{os.getpid()}.tmp"
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=1, sort_keys=True)
    os.replace(tmp, path)


def read_json(path: str):
    """Read a JSON file; a ``ValueError`` names the file when it cannot be read."""
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: cannot read it ({type(e).__name__}: {e})") from None


def sha256_file(path: str) -> str:
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def _snapshot(folder: str) -> dict:
    snap = {}
    for root, _, files in os.walk(folder):
        for f in files:
            p = os.path.join(root, f)
            try:
                st = os.stat(p)
            except OSError:
                continue
            snap[os.path.relpath(p, folder)] = (st.st_mtime_ns, st.st_size)
    return snap


def run_suite(name: str, args: SuiteArgs) -> dict:
    """Run one suite, several (``"lattice,speed"``) or ``all``; write ``OUT/metrics.json`` and
    ``OUT/run.json`` (replacing an earlier run's, see the module docstring); return the metrics."""
    args.validate()
    names = suite_names(name)
    load_builtin_suites()
    missing = [n for n in names if n not in SUITES]
    if missing:
        raise ValueError(f"suite {missing[0]!r} is listed but did not register itself")
    os.makedirs(args.out, exist_ok=True)
    before, start_ns = _snapshot(args.out), time.time_ns()
    metrics: dict[str, float] = {}
    for n in names:
        t0 = time.perf_counter()
        for k, v in SUITES[n](args).items():
            metrics[f"{n}.{k}"] = v
        metrics[f"{n}.wall_s"] = round(time.perf_counter() - t0, 3)
    after = _snapshot(args.out)
    ours = {METRICS, RUN}
    outputs = sorted(
        p
        for p, st in after.items()
        if p not in ours and not p.endswith(".tmp") and (before.get(p) != st or st[0] >= start_ns)
    )
    path = os.path.join(args.out, METRICS)
    if os.path.exists(path) or os.path.exists(os.path.join(args.out, RUN)):
        print(
            f"jaxplan: replacing {path} and {RUN} of an earlier run (one run per folder, never merged)", file=sys.stderr
        )
    write_json_atomic(path, metrics)
    from jaxplan import __version__

    write_json_atomic(
        os.path.join(args.out, RUN),
        {
            "jaxplan": __version__,
            "suites": names,
            "args": asdict(args),
            "outputs": outputs,
            "metrics_sha256": sha256_file(path),
        },
    )
    return metrics
