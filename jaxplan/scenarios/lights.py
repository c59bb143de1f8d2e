"""Traffic lights on a scene's route: the stop lines the route crosses, which light governs each,
and its color at every step (built on the host, read under jit).

Which light governs: a route lanelet that references traffic lights (``Lane.traffic_lights``)
governs the route at its stop line (``Lane.stop_line``; the lanelet's end where the map draws no
line) when the route crosses that line. The movement the route makes there is the heading change
from the lanelet's end to the end of the next route lanelet (its successor): ``straight`` within
``STRAIGHT_TURN``, else ``left`` (counter-clockwise) or ``right``. The lights whose ``direction``
covers that movement govern the line: at each step the most specific of them (fewest movements)
that is not ``inactive`` gives its color (a right-turn arrow over the main light, the main light
while the arrow is dark). When the movement is unknown (the route ends on the lanelet, or leaves
it sideways) or no light covers it, every light the lanelet references governs, and the most
restrictive color of those not ``inactive`` holds (red, red-yellow, yellow, green). A line whose
governing lights are all ``inactive`` at a step is ``inactive`` then (no signal: nothing to stop for).

Storage: a line's colors repeat with the least common multiple of its lights' periods, so one
period of them is kept from scene step 0 (``color (NL, P)``, ``period (NL,)``): the color at scene
step ``k`` is ``color[j, k mod period[j]]``, exact at every step of any drive.
"""

from __future__ import annotations

import math
from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxplan.scenarios.fields import ScenarioError
from jaxplan.scenarios.scenario import LIGHT_COLORS, LIGHT_DIRECTIONS
from jaxplan.types import pytree_dataclass

GREEN, YELLOW, RED, RED_YELLOW, INACTIVE = (
    LIGHT_COLORS.index(c) for c in ("green", "yellow", "red", "redYellow", "inactive")
)
STRAIGHT_TURN = math.radians(30.0)  # a heading change within this through a junction is straight on
MAX_PERIOD = 20000  # steps: a line whose lights repeat less often than this is refused
LINE_MARGIN = 0.25  # m: the route crosses a stop line within this beyond its ends
_RESTRICT = {GREEN: 0, YELLOW: 1, RED_YELLOW: 2, RED: 3}  # most restrictive wins where ambiguous


@pytree_dataclass(data_fields=("line", "s", "color", "period", "lanelet", "valid"))
class TrafficLights:
    """The stop lines on a scene's route and their colors (``NL`` lines, ``P`` steps of colors).

    Attributes:
        line: ``(NL, 2, 2)`` the stop line's ends (local frame).
        s: ``(NL,)`` arc length on the route where the route crosses it.
        color: ``(NL, P)`` int, the line's color (index into ``LIGHT_COLORS``: ``GREEN``, ``YELLOW``,
            ``RED``, ``RED_YELLOW``, ``INACTIVE``) at scene steps ``0 .. period - 1``; it repeats.
        period: ``(NL,)`` int, steps after which the colors repeat (``1 <= period <= P``).
        lanelet: ``(NL,)`` int, the route lanelet the line belongs to (-1 for padding).
        valid: ``(NL,)`` bool; padding is invalid (and ``INACTIVE``).
    """

    line: Any
    s: Any
    color: Any
    period: Any
    lanelet: Any
    valid: Any

    def validate(self) -> TrafficLights:
        """Host-side checks of shapes and values (``ValueError`` naming the field)."""
        line, s = np.asarray(self.line), np.asarray(self.s)
        color, period, valid = np.asarray(self.color), np.asarray(self.period), np.asarray(self.valid)
        lead = s.shape
        if (
            line.shape != lead + (2, 2)
            or np.asarray(self.lanelet).shape != lead
            or valid.shape != lead
            or period.shape != lead
            or color.shape[:-1] != lead
        ):
            raise ValueError(
                f"Scene.lights: expected line (..., NL, 2, 2), s / period / lanelet / valid (..., NL) "
                f"and color (..., NL, P), got {line.shape}, {s.shape}, {period.shape}, "
                f"{np.asarray(self.lanelet).shape}, {valid.shape}, {color.shape}"
            )
        if line.size and not np.all(np.isfinite(line[valid])) or s.size and not np.all(np.isfinite(s[valid])):
            raise ValueError("Scene.lights.line / s: contain NaN or inf")
        if not np.issubdtype(color.dtype, np.integer) or np.any((color < 0) | (color >= len(LIGHT_COLORS))):
            raise ValueError(f"Scene.lights.color: expected ints in [0, {len(LIGHT_COLORS)})")
        if not np.issubdtype(period.dtype, np.integer) or np.any((period < 1) | (period > color.shape[-1])):
            raise ValueError(f"Scene.lights.period: expected ints in [1, {color.shape[-1]}]")
        return self


def no_lights() -> TrafficLights:
    """A scene without stop lines (``NL = 0``)."""
    return TrafficLights(
        np.zeros((0, 2, 2)),
        np.zeros(0),
        np.zeros((0, 1), np.int32),
        np.ones(0, np.int32),
        np.zeros(0, np.int32),
        np.zeros(0, bool),
    )


def pad_lights(lights: TrafficLights, NL: int, P: int) -> TrafficLights:
    """Pad to ``NL`` lines and ``P`` steps of colors: extra lines invalid and ``INACTIVE``, extra steps
    repeat the last (never read: ``period`` stays)."""
    n, p = lights.color.shape
    color = np.asarray(lights.color, np.int32)
    if P > p:
        color = np.concatenate([color, np.repeat(color[:, -1:] if p else np.zeros((n, 1), np.int32), P - p, 1)], 1)
    if NL <= n:
        return TrafficLights(
            np.asarray(lights.line),
            np.asarray(lights.s),
            color,
            np.asarray(lights.period),
            np.asarray(lights.lanelet),
            np.asarray(lights.valid),
        )
    k = NL - n
    return TrafficLights(
        np.concatenate([np.asarray(lights.line, float), np.zeros((k, 2, 2))]),
        np.concatenate([np.asarray(lights.s, float), np.zeros(k)]),
        np.concatenate([color, np.full((k, color.shape[1]), INACTIVE, np.int32)]),
        np.concatenate([np.asarray(lights.period, np.int32), np.ones(k, np.int32)]),
        np.concatenate([np.asarray(lights.lanelet, np.int32), np.full(k, -1, np.int32)]),
        np.concatenate([np.asarray(lights.valid, bool), np.zeros(k, bool)]),
    )


def colors_at(lights: TrafficLights, steps):
    """``(..., NL)`` int: each line's color at integer scene ``steps (...)`` (jittable; one scene).
    Invalid lines are ``INACTIVE``."""
    steps = jnp.asarray(steps)
    period = jnp.maximum(jnp.asarray(lights.period), 1)
    idx = jnp.mod(steps[..., None], period)  # (..., NL)
    NL = period.shape[-1]
    c = jnp.asarray(lights.color)[jnp.arange(NL), idx]
    return jnp.where(jnp.asarray(lights.valid), c, INACTIVE)


def must_stop(color):
    """``(...)`` bool: the color forbids crossing the line (red, red-yellow)."""
    return (color == RED) | (color == RED_YELLOW)


# ----------------------------------------------------------------------------- host: building


def movement(lane, nxt) -> str | None:
    """``left``, ``straight`` or ``right``: the turn from ``lane``'s end to ``nxt``'s end (None without ``nxt``)."""
    if nxt is None:
        return None
    a, b = lane.center[-1] - lane.center[-2], nxt.center[-1] - nxt.center[-2]
    turn = math.atan2(a[0] * b[1] - a[1] * b[0], float(np.dot(a, b)))
    return "straight" if abs(turn) <= STRAIGHT_TURN else "left" if turn > 0 else "right"


def _most_restrictive(codes: np.ndarray) -> np.ndarray:
    """``(S,)`` the most restrictive color of ``codes (n, S)`` not ``INACTIVE`` at each step (else ``INACTIVE``)."""
    rank = np.full(codes.shape, -1)
    for c, r in _RESTRICT.items():
        rank[codes == c] = r
    pick = np.take_along_axis(codes, np.argmax(rank, axis=0)[None], 0)[0]
    return np.where(rank.max(0) >= 0, pick, INACTIVE).astype(np.int32)


def line_colors(lights: list, move: str | None, where: str = "") -> tuple[np.ndarray, int]:
    """One period ``(period,)`` of a stop line's colors governed by ``lights`` (``TrafficLight``s of one
    lanelet) for the route's movement ``move`` (see the module docstring), and the period."""
    period = 1
    for tl in lights:
        period = math.lcm(period, max(1, tl.period) if tl.active and tl.colors else 1)
    if period > MAX_PERIOD:
        raise ScenarioError(
            f"{where}: traffic lights {[tl.id for tl in lights]} repeat only every {period} steps "
            f"(more than {MAX_PERIOD})"
        )
    steps = np.arange(period)
    match = [tl for tl in lights if move is not None and move in LIGHT_DIRECTIONS[tl.direction]]
    if not match:  # ambiguous: every light, the most restrictive one on
        return _most_restrictive(np.stack([tl.color_codes(steps) for tl in lights])), period
    out = np.full(period, INACTIVE, np.int32)
    for width in sorted({len(LIGHT_DIRECTIONS[tl.direction]) for tl in match}, reverse=True):
        # widest first: the narrower (more specific) lights decide where they are on
        c = _most_restrictive(
            np.stack([tl.color_codes(steps) for tl in match if len(LIGHT_DIRECTIONS[tl.direction]) == width])
        )
        out = np.where(c != INACTIVE, c, out)
    return out, period


def _crossing(ref_xy: np.ndarray, ref_s: np.ndarray, line: np.ndarray) -> float | None:
    """Arc length where polyline ``ref_xy (R, 2)`` first crosses segment ``line (2, 2)`` (extended by
    ``LINE_MARGIN`` at both ends), or None."""
    a, b = line
    d = b - a
    n = np.linalg.norm(d)
    if n < 1e-9:
        return None
    u = d / n
    a, d = a - LINE_MARGIN * u, d + 2 * LINE_MARGIN * u
    p, q = ref_xy[:-1], ref_xy[1:] - ref_xy[:-1]
    den = q[:, 0] * d[1] - q[:, 1] * d[0]
    w = a - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[:, 0] * d[1] - w[:, 1] * d[0]) / den  # along the route segment
        r = (w[:, 0] * q[:, 1] - w[:, 1] * q[:, 0]) / den  # along the stop line
    hit = (np.abs(den) > 1e-12) & (t >= 0) & (t <= 1) & (r >= 0) & (r <= 1)
    if not hit.any():
        return None
    i = int(np.argmax(hit))
    return float(ref_s[i] + t[i] * (ref_s[i + 1] - ref_s[i]))


def route_lights(scenario, route, ref_xy: np.ndarray, ref_s: np.ndarray) -> TrafficLights:
    """The ``TrafficLights`` governing a route (see the module docstring), in route order.

    Args:
        scenario: the loaded ``Scenario`` (its lanes' ``traffic_lights`` / ``stop_line`` and its
            ``traffic_lights``).
        route: its ``Route`` (the lanelet sequence).
        ref_xy: ``(R, 2)`` the scene's route line; ref_s: ``(R,)`` its arc lengths.

    Raises:
        ScenarioError: a stop line's lights repeat less often than every ``MAX_PERIOD`` steps.
    """
    by_id = {ln.id: ln for ln in scenario.lanes}
    lights = {tl.id: tl for tl in getattr(scenario, "traffic_lights", ())}
    rows = []
    seq = list(route.lanelets)
    for i, lid in enumerate(seq):
        lane = by_id.get(lid)
        if lane is None or not lane.traffic_lights or lane.stop_line is None:
            continue
        s = _crossing(ref_xy, ref_s, np.asarray(lane.stop_line, float))
        if s is None:  # the route does not cross this lanelet's line (it leaves the lanelet sideways)
            continue
        nxt = seq[i + 1] if i + 1 < len(seq) else None
        nxt = by_id[nxt] if nxt in lane.successors and nxt in by_id else None
        gov = [lights[j] for j in lane.traffic_lights if j in lights]
        if not gov:
            continue
        color, period = line_colors(gov, movement(lane, nxt), f"scenario {scenario.id}, lanelet {lid}")
        rows.append((np.asarray(lane.stop_line, float), s, color, period, lid))
    if not rows:
        return no_lights()
    P = max(r[3] for r in rows)
    color = np.stack([np.concatenate([r[2], np.full(P - r[3], r[2][-1], np.int32)]) for r in rows])
    return TrafficLights(
        np.stack([r[0] for r in rows]),
        np.array([r[1] for r in rows], float),
        color,
        np.array([r[3] for r in rows], np.int32),
        np.array([r[4] for r in rows], np.int32),
        np.ones(len(rows), bool),
    )
