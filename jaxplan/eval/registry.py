"""Suites register themselves here; ``jaxplan eval SUITE`` runs them."""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from typing import Callable

SUITES: dict[str, Callable] = {}


@dataclass(frozen=True)
class SuiteArgs:
    """What every suite receives from the CLI."""

    out: str
    n: int | None = None
    seed: int = 0
    quick: bool = False
    scenarios: str | None = None
    weights: str | None = None


def register(name: str):
    """Decorator: ``fn(args: SuiteArgs) -> dict[str, float]`` becomes suite ``name``."""

    def wrap(fn):
        SUITES[name] = fn
        return fn

    return wrap


def _load_builtin_suites():
    """Import every ``jaxplan/eval/*_suite.py``; each registers itself."""
    import importlib
    import pkgutil

    import jaxplan.eval as pkg

    for mod in pkgutil.iter_modules(pkg.__path__):
        if mod.name.endswith("_suite"):
            importlib.import_module(f"jaxplan.eval.{mod.name}")


def run_suite(name: str, args: SuiteArgs) -> dict:
    """Run one suite (or ``all``), write ``OUT/metrics.json`` and return the metrics."""
    _load_builtin_suites()
    names = sorted(SUITES) if name == "all" else [name]
    unknown = [n for n in names if n not in SUITES]
    if unknown:
        raise ValueError(f"unknown suite {unknown[0]!r}; known: {', '.join(['all'] + sorted(SUITES))}")
    os.makedirs(args.out, exist_ok=True)
    metrics: dict[str, float] = {}
    for n in names:
        t0 = time.perf_counter()
        for k, v in SUITES[n](args).items():
            metrics[f"{n}.{k}"] = v
        metrics[f"{n}.wall_s"] = round(time.perf_counter() - t0, 3)
    path = os.path.join(args.out, "metrics.json")
    old = {}
    if os.path.exists(path):
        with open(path) as f:
            old = json.load(f)
    old.update(metrics)
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(old, f, indent=1, sort_keys=True)
    os.replace(tmp, path)
    return metrics
