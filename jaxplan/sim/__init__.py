"""Closed-loop driving: ``rollout`` (any ``Planner`` over a batch of ``Scene``s), the tracking
models, the driving metrics and ``drive`` (files in, per-scenario outputs and a report out)."""

from jaxplan.sim.metrics import METRICS, evaluate, register_metric
from jaxplan.sim.metrics.registry import evaluate_batch
from jaxplan.sim.rollout import ChunkedRollout, DriveLog, SimConfig, drive_one, driven_scene, rollout

__all__ = [
    "ChunkedRollout",
    "DriveLog",
    "SimConfig",
    "drive_one",
    "driven_scene",
    "rollout",
    "METRICS",
    "evaluate",
    "evaluate_batch",
    "register_metric",
]
