"""The metric registry (see the package docstring)."""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax
from jaxtyping import Array, Shaped

METRICS: dict[str, Callable] = {}


def register_metric(name: str):
    """Decorator: ``fn(log, scene, vehicle) -> {figure: () array}`` becomes metric ``name``;
    its figures are reported as ``name.figure``."""

    def wrap(fn):
        METRICS[name] = fn
        return fn

    return wrap


def evaluate(log, scene, vehicle, names=None) -> dict[str, Shaped[Array, ""]]:
    """Every metric (or those in ``names``) of one drive (unbatched ``log`` and ``scene``)."""
    out = {}
    for name in names or sorted(METRICS):
        for k, v in METRICS[name](log, scene, vehicle).items():
            out[f"{name}.{k}"] = v
    return out


def evaluate_batch(log, scene, vehicle, names=None, batch_size: int | None = None) -> dict:
    """``evaluate`` over a leading batch axis of ``log`` and ``scene``, one scene at a time by
    default (``lax.map``): the off-road test then skips lanelets far from the drive, which a
    ``vmap`` would evaluate anyway, and memory stays that of one scene."""
    return _evaluate_batch(log, scene, vehicle, tuple(names) if names else None, batch_size)


@functools.partial(jax.jit, static_argnames=("vehicle", "names", "batch_size"))
def _evaluate_batch(log, scene, vehicle, names, batch_size):
    return jax.lax.map(lambda ls: evaluate(ls[0], ls[1], vehicle, names), (log, scene), batch_size=batch_size)
