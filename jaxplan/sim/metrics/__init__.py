"""Driving metrics computed in JAX from a drive's log, one small module each (as Waymax
keeps them): ``overlap`` (collision, at fault), ``offroad``, ``goal``, ``progress``,
``comfort``, ``ttc``, ``redlight`` (stop lines crossed against the light), ``blindzone``
(time in a moving neighbour's blind zone). Each registers a
function ``(log, scene, vehicle) -> dict`` of
per-drive ``()`` arrays named ``<metric>.<figure>``; ``evaluate`` runs them all (``vmap``
over a batch). A new metric is one module that calls ``register_metric``; the drive
summary and the report pick it up by name.
"""

from jaxplan.sim.metrics import (  # noqa: F401  (they register)
    blindzone,
    comfort,
    goal,
    offroad,
    overlap,
    progress,
    redlight,
    ttc,
)
from jaxplan.sim.metrics.registry import METRICS, evaluate, register_metric

__all__ = ["METRICS", "evaluate", "register_metric"]
