"""Timing and output helpers shared by the benchmark scripts (``experiments/bench_*.py``)."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable

import numpy as np


def best_time(fn: Callable[[], object], reps: int) -> float:
    """Best wall time (s) of ``reps`` calls of ``fn`` (which must block until done)."""
    best = np.inf
    for _ in range(max(1, reps)):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def best_times_interleaved(fns: dict, reps: int, inner: int = 1) -> dict:
    """Best wall time (s) of each of ``fns`` (name -> callable that blocks until done) over
    ``reps`` rounds, each round calling every one ``inner`` times in turn: peers are sampled over
    the same stretch of time, so a shared machine's drifting speed does not fall on one side only
    (``inner > 1``: each side's later calls in a round run warm, after the other side's work)."""
    best = {name: np.inf for name in fns}
    for _ in range(max(1, reps)):
        for name, fn in fns.items():
            for _ in range(max(1, inner)):
                t = time.perf_counter()
                fn()
                best[name] = min(best[name], time.perf_counter() - t)
    return best


def timed(fn: Callable[[], object]) -> tuple[object, float]:
    """``(fn(), seconds)`` for one call, e.g. the first (compiling) call."""
    t = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t


def write_figures(figures: dict, out: str, width: int = 48, extra: dict | None = None) -> None:
    """Print ``figures`` one per line and write them as JSON to ``out``, with ``extra`` (long
    entries, e.g. per-case rows) added to the file but not printed."""
    for k, v in figures.items():
        print(f"{k:{width}s} {v:,.4g}" if isinstance(v, float) else f"{k:{width}s} {v}")
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    with open(out, "w") as f:
        json.dump({**figures, **(extra or {})}, f, indent=1)
    print(f"wrote {out}")
