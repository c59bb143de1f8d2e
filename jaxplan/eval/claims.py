"""The project's headline claims, each read from a run's figures.

A claim names the figure that decides it (a ``metrics.json`` key, or the ratio of two), the
comparison and the target. ``judge(metrics)`` gives one row per claim: the value, and whether it
is met, or ``None`` when this run did not measure it (a suite not run, or run without the input
the figure needs). The report (``jaxplan report``) opens with these rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Claim:
    """One claim.

    Attributes:
        topic: the part of the library it is about (``"path bounds"``, ``"park-out"``).
        text: the claim in a few words.
        figure: the deciding figure: a key, or ``"A / B"`` for the ratio of two keys.
        op: ``"<="``, ``">="`` or ``"=="``.
        target: the number it is compared with.
    """

    topic: str
    text: str
    figure: str
    op: str
    target: float


CLAIMS = (
    Claim(
        "path bounds",
        "contour corners bound the path >= 3x closer than the centre line (radius <= 12 m)",
        "bounds.claim.r_le12.centerline_over_contour",
        ">=",
        3.0,
    ),
    Claim("park-out", "grid park-out never collides", "parkout.claim.grid_runs_with_collision", "==", 0),
    Claim(
        "park-out",
        "grid park-out gets out of every slot >= the analytic minimum",
        "parkout.claim.success_rate_slot_ge_min",
        ">=",
        1.0,
    ),
    Claim(
        "park-out",
        "park-out gets out of every slot with >= 1.5 m spare",
        "parkout.claim.success_rate_spare_ge_1.5",
        ">=",
        1.0,
    ),
    Claim(
        "lazy replanning",
        "lazy re-planning: >= 5x fewer re-plans than periodic",
        "replan.claim.periodic_over_lazy_replans",
        ">=",
        5.0,
    ),
    Claim(
        "lazy replanning",
        "lazy re-planning: no more collisions than periodic (share difference)",
        "replan.claim.lazy_minus_periodic_collision_share",
        "<=",
        0.0,
    ),
    Claim(
        "weights by imitation",
        "tuned weights: ADE3 >= 20 % below the default weights",
        "lattice.imitation.weights.ade3 / lattice.imitation.default.ade3",
        "<=",
        0.8,
    ),
    Claim(
        "weights by imitation",
        "tuned weights: ADE3 below constant velocity",
        "lattice.imitation.weights.ade3 / lattice.imitation.constant_velocity.ade3",
        "<=",
        1.0,
    ),
)


def value(metrics: dict, figure: str) -> float | None:
    """The figure's value in ``metrics``, or ``None`` when a key is missing or not finite."""
    keys = [k.strip() for k in figure.split(" / ")]
    raw = [metrics.get(k) for k in keys]
    vals = [float(v) for v in raw if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)]
    if len(vals) != len(raw):
        return None
    if len(vals) == 1:
        return vals[0]
    return vals[0] / vals[1] if vals[1] else None


def met(v: float, op: str, target: float) -> bool:
    """Whether ``v op target`` holds (``==`` within 1e-9)."""
    if op == "<=":
        return v <= target
    if op == ">=":
        return v >= target
    if op == "==":
        return abs(v - target) <= 1e-9
    raise ValueError(f"op: expected one of <=, >=, ==, got {op!r}")


def judge(metrics: dict, claims=CLAIMS) -> list:
    """Rows ``(claim, value or None, met or None)``, one per claim."""
    rows = []
    for c in claims:
        v = value(metrics, c.figure)
        rows.append((c, v, None if v is None else met(v, c.op, c.target)))
    return rows


def claims_table(metrics: dict, claims=CLAIMS) -> list:
    """Markdown lines of the claims table."""
    lines = ["| topic | claim | figure | value | target | met |", "| --- | --- | --- | --- | --- | --- |"]
    for c, v, ok in judge(metrics, claims):
        shown = "not measured in this run" if v is None else f"{v:.4g}"
        verdict = "-" if ok is None else ("yes" if ok else "**no**")
        lines.append(f"| {c.topic} | {c.text} | `{c.figure}` | {shown} | {c.op} {c.target:g} | {verdict} |")
    return lines
