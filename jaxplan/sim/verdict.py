"""The one verdict of a drive, for every planner and every peer, and why a goal was missed.

**Success** (what makes a CommonRoad solution valid): the goal is reached by CommonRoad's
rule (``goal`` metric), there is no collision at any step (``overlap``) and the car never
leaves the road (``offroad``). Fault is judged at every obstacle's first contact
(``jaxplan.sim.metrics.overlap``). Red lights run (``redlight``, where the scene has lights)
are reported beside it.

The same code judges jaxplan's drives (from the simulator's log) and any other planner's
``driven.json`` (``judge_states``): the metrics are computed by the same JAX functions from
the states, against the same ``Scene``.

``explain`` says, for a drive that did not succeed, what happened: the collision (with what,
at fault or hit from behind, at what speed), leaving the road, or why the goal was missed
(standing before it and what stood ahead, out of time, through the region before its time
window, in it at the wrong speed or heading, goal region off the map, ...).
"""

from __future__ import annotations

import math

import numpy as np

STAND = 0.3  # m/s: slower counts as standing
CRAWL = 2.0  # m/s


def success(row: dict) -> bool:
    """Goal reached, no collision at any step, never off road."""
    return bool(row.get("goal.reached")) and not row.get("overlap.collided") and not row.get("offroad.offroad")


def outcome(row: dict) -> str:
    """One word for a drive: ``success``, ``collision``, ``off road``, ``goal off map`` or ``goal missed``."""
    if success(row):
        return "success"
    if row.get("overlap.collided"):
        return "collision"
    if row.get("offroad.offroad"):
        return "off road"
    if row.get("goal.off_map"):
        return "goal off map"
    return "goal missed"


def _frenet(route_xy: np.ndarray, p: np.ndarray) -> tuple[float, float]:
    """Host ``(s, l)`` of point ``p`` on polyline ``route_xy (R, 2)``."""
    seg = route_xy[1:] - route_xy[:-1]
    L2 = np.maximum(np.sum(seg * seg, 1), 1e-12)
    u = np.clip(np.sum((p - route_xy[:-1]) * seg, 1) / L2, 0.0, 1.0)
    d = np.linalg.norm(route_xy[:-1] + u[:, None] * seg - p, axis=1)
    j = int(np.argmin(d))
    s0 = np.concatenate([[0.0], np.cumsum(np.sqrt(L2))])
    t = seg[j] / math.sqrt(L2[j])
    r = p - route_xy[j]
    return float(s0[j] + u[j] * math.sqrt(L2[j])), float(t[0] * r[1] - t[1] * r[0])


def _ahead(scene, step: int, xy, heading, types=None) -> str:
    """The nearest obstacle ahead of the car within its lane's width (40 m), as words."""
    obs = scene.obstacles
    b = np.asarray(obs.boxes)
    v = np.asarray(obs.valid)
    st = np.asarray(obs.static)
    T = b.shape[1]
    k = min(step, T - 1)
    c, s = math.cos(heading), math.sin(heading)
    best = None
    for i in range(b.shape[0]):
        j = k if not st[i] else int(np.argmax(v[i]))
        if not (v[i, j] or (st[i] and v[i].any())) or (not st[i] and step >= T):
            continue
        rx, ry = b[i, j, 0] - xy[0], b[i, j, 1] - xy[1]
        along, across = rx * c + ry * s, -rx * s + ry * c
        if 0 < along < 40.0 and abs(across) < 2.5 and (best is None or along < best[0]):
            speed = 0.0
            if not st[i] and j + 1 < T and v[i, j + 1]:
                speed = float(np.hypot(*(b[i, j + 1, :2] - b[i, j, :2]))) / float(scene.dt)
            best = (along, i, speed)
    if best is None:
        return ""
    along, i, speed = best
    kind = f"{types[i]} " if types is not None and i < len(types) else ""
    ident = f"obstacle {i}"
    motion = "standing" if speed < STAND else f"moving at {speed:.1f} m/s"
    return f"{kind}{ident} {along:.0f} m ahead ({motion})"


def first_miss_step(row: dict, end_step: int) -> int:
    """The step at which a drive first went wrong: its first collision or its first step off the
    road, whichever came first; else its last step (``end_step``)."""
    steps = [end_step]
    if row.get("overlap.collided"):
        steps.append(int(row["overlap.first_step"]))
    if row.get("offroad.offroad") and int(row.get("offroad.first_step", -1)) >= 0:
        steps.append(int(row["offroad.first_step"]))
    return min(steps)


def explain(row: dict, log: dict, scene, types=None, describe: str = "") -> str:
    """Why a drive did not succeed, in one line ("" for a success).

    Args:
        row: the drive's metrics (``<metric>.<figure>`` keys).
        log: the drive's states as numpy arrays ``t, x, y, heading, v`` ``(N,)`` (box centre, local
            frame) and ``end_step``.
        scene: the unbatched numpy ``Scene`` the drive was judged on (its obstacles where the traffic was).
        types: obstacle type names ``(K,)`` (for the words), optional.
        describe: what the planner said of its last plans (its mode), optional.
    """
    if success(row):
        return ""
    t = np.asarray(log["t"], float)
    x, y = np.asarray(log["x"], float), np.asarray(log["y"], float)
    hd, v = np.asarray(log["heading"], float), np.asarray(log["v"], float)
    n = int(log["end_step"]) + 1
    parts = []
    if row.get("overlap.collided"):
        k = int(row["overlap.first_step"])
        who = int(row["overlap.obstacle"])
        kind = f"{types[who]} " if types is not None and 0 <= who < len(types) else ""
        if row.get("overlap.at_fault"):
            kf = int(row["overlap.fault_step"])
            wf = int(row["overlap.fault_obstacle"])
            kindf = f"{types[wf]} " if types is not None and 0 <= wf < len(types) else ""
            parts.append(f"collision, at fault: drove into {kindf}obstacle {wf} at t = {t[kf]:.1f} s ({v[kf]:.1f} m/s)")
        else:
            how = "standing" if v[k] < STAND else ("crawling" if v[k] < CRAWL else f"at {v[k]:.1f} m/s")
            parts.append(f"collision, hit from behind by {kind}obstacle {who} at t = {t[k]:.1f} s while {how}")
    if row.get("offroad.offroad"):
        k = int(row.get("offroad.first_step", -1))
        parts.append(f"off road at t = {t[k]:.1f} s" if k >= 0 else "off road")
    if not row.get("goal.reached"):
        parts.append(_why_missed(row, t[:n], x[:n], y[:n], hd[:n], v[:n], scene, types))
    if describe:
        parts.append(f"planner: {describe}")
    return "; ".join(p for p in parts if p)


def _why_missed(row, t, x, y, hd, v, scene, types) -> str:
    g = scene.goal
    g_t = np.asarray(g.time, float)
    g_v = np.asarray(g.speed, float)
    has_region = bool(np.asarray(g.has_region))
    if row.get("goal.off_map"):
        return "goal missed: the goal region lies off the lanelets (past the map's end)"
    route = np.asarray(scene.route.xy, float)
    s_rng = np.asarray(g.s_range, float)
    sl = np.array([_frenet(route, np.array([x[k], y[k]])) for k in range(len(t))])
    s_end = sl[-1, 0]
    ended_early = t[-1] < g_t[0] - 1e-6
    standing = np.nonzero(v >= STAND)[0]
    stood_for = t[-1] - (t[standing[-1]] if len(standing) else t[0])
    if has_region:
        inside = _in_region(g, x, y)
        if inside.any():
            k = int(np.argmax(inside))
            if t[k] < g_t[0]:
                return (
                    f"goal missed: in the goal region at t = {t[k]:.1f} s, before its time window "
                    f"[{g_t[0]:.1f}, {g_t[1]:.1f}] s"
                )
            in_window = inside & (t >= g_t[0] - 1e-3) & (t <= g_t[1] + 1e-3)
            if in_window.any():
                k = int(np.argmax(in_window))
                if not (g_v[0] - 1e-6 <= v[k] <= g_v[1] + 1e-6):
                    return (
                        f"goal missed: in the goal region in its time window at {v[k]:.1f} m/s, outside its "
                        f"speed range [{g_v[0]:.1f}, {g_v[1]:.1f}]"
                    )
                return "goal missed: in the goal region in its time window with a heading outside its range"
            return f"goal missed: in the goal region only after its time window closed at {g_t[1]:.1f} s"
        short = s_rng[0] - s_end
        lateral = abs(sl[-1, 1])
        if short <= 0 and lateral > 2.0:
            return f"goal missed: passed the goal region {lateral:.1f} m to the side of it (another lane)"
        if stood_for >= 2.0 and short > 0:
            what = _ahead(scene, len(t) - 1, (x[-1], y[-1]), hd[-1], types)
            return f"goal missed: stood for the last {stood_for:.1f} s, {short:.0f} m before the goal region" + (
                f", behind {what}" if what else ", nothing ahead in its lane"
            )
        if short > 0:
            mean_v = (s_end - sl[0, 0]) / max(t[-1] - t[0], 1e-9)
            return (
                f"goal missed: {short:.0f} m short of the goal region when the drive ended at t = {t[-1]:.1f} s "
                f"(mean speed {mean_v:.1f} m/s" + (", ended before the goal's time window" if ended_early else "") + ")"
            )
        return f"goal missed: past the goal region's start without entering it ({sl[-1, 1]:+.1f} m off the route)"
    # time-only goals (and their speed / heading ranges)
    if t[-1] < g_t[0] - 1e-6:
        return (
            f"goal missed: the drive ended at t = {t[-1]:.1f} s, before the goal's time window opened at {g_t[0]:.1f} s"
        )
    k = int(np.argmin(np.abs(t - g_t[0])))
    if not (g_v[0] - 1e-6 <= v[k] <= g_v[1] + 1e-6):
        return f"goal missed: {v[k]:.1f} m/s in the goal's time window, outside its speed range [{g_v[0]:.1f}, {g_v[1]:.1f}]"
    return "goal missed: heading outside the goal's range in its time window"


def _in_region(goal, x, y) -> np.ndarray:
    """``(N,)`` bool: the points lie in one of the goal's polygons (host even-odd rule)."""
    from jaxplan.scenarios.route import point_in_polygon

    reg = np.asarray(goal.region, float)
    ok = np.asarray(goal.region_valid, bool)
    out = np.zeros(len(x), bool)
    for poly, m in zip(reg, ok):
        if not m.any():
            continue
        p = poly[m]
        out |= np.array([point_in_polygon(p, np.array([a, b])) for a, b in zip(x, y)])
    return out
