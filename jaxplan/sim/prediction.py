"""What the planner sees of the traffic at a planning cycle (``SimConfig.prediction``).

Planners read the obstacles only through ``jaxplan.plan_context.road_context``, which windows
``scene.obstacles`` and ``scene.obstacle_sl`` from the cycle's step. So the simulator hands the
planner a **view**: a copy of the scene whose obstacle boxes, ``valid`` and ``obstacle_sl``
hold the predictions at steps ``[step, step + H)`` (``with_predictions``) and nothing else (no
recorded state outside the window).

- ``oracle`` with ``idm`` agents (``anchored_predictions``): each agent's recorded motion
  re-anchored where it actually is: its recorded future displacement along its path
  (``jaxplan.sim.agents``) from its current position; present where it was recorded.
  (With ``log`` agents the planner sees the scene itself: the recorded future.)
- ``cv`` (``cv_predictions``): only the present. Each obstacle's current box, heading and speed
  (with log agents: the speed of its last recorded step, the next one at its first step; with
  IDM agents: their simulated speed) extrapolated at constant speed along its lane: the
  ``Scene.lane_paths`` path nearest its centre among those within ``LANE_MATCH_DIST`` metres
  that run within ``LANE_MATCH_ANGLE`` of its heading (ties go to the path that starts
  nearest behind it), keeping its lateral offset from the path's centre line, its heading
  the path's, straight on past the path's end. Without such a path, and for pedestrians:
  straight along its heading. Every obstacle present now is predicted over the whole
  horizon; static ones hold their box.

Frenet coordinates of predicted centres: interpolated from the recording (re-anchored
oracle) or refined by Newton steps on the route from an interpolated guess (``frenet_near``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
from jax import lax

from jaxplan.geometry.frenet import frenet_points, ref_state
from jaxplan.scenarios.scene import OBSTACLE_TYPES
from jaxplan.sim.agents import AgentPaths, AgentState, agent_boxes, path_frenet, path_pose
from jaxplan.types import Obstacles, pytree_dataclass

PREDICTIONS = ("oracle", "cv")
LANE_MATCH_DIST = 2.0  # m: an obstacle farther than this from every lane path goes straight
LANE_MATCH_ANGLE = math.pi / 4  # its heading within this of the path's direction
LANE_MATCH_TIE = 0.01  # score per metre along the path: of equally near paths, the one starting nearest behind
PEDESTRIAN = OBSTACLE_TYPES.index("pedestrian")


@pytree_dataclass(data_fields=("x", "y", "valid", "sigma", "theta", "route_s", "n"))
class LanePaths:
    """``Scene.lane_paths`` ready for look-ups (one scene, ``LP`` paths of ``Q`` points), points on
    the leading axis (XLA's CPU backend reduces small trailing axes slowly).

    Attributes:
        x, y: ``(Q, LP)`` points; valid: ``(Q, LP)``.
        sigma: ``(Q, LP)`` arc length along each path.
        theta: ``(Q, LP)`` unwrapped direction at each point (mean of the adjoining chords).
        route_s: ``(Q, LP)`` Frenet ``s`` of each point on the route.
        n: ``(LP,)`` int, valid points (a prefix).
    """

    x: Any
    y: Any
    valid: Any
    sigma: Any
    theta: Any
    route_s: Any
    n: Any


def lane_cache(scene) -> LanePaths | None:
    """``LanePaths`` of one scene (once per drive), or None without ``Scene.lane_paths``."""
    if scene.lane_paths is None:
        return None
    xy = jnp.swapaxes(jnp.asarray(scene.lane_paths, scene.route.xy.dtype), 0, 1)  # (Q, LP, 2)
    ok = jnp.swapaxes(jnp.asarray(scene.lane_path_valid, bool), 0, 1)
    x, y = xy[..., 0], xy[..., 1]
    n = jnp.sum(ok, axis=0)
    dx, dy = x[1:] - x[:-1], y[1:] - y[:-1]
    seg_ok = ok[1:] & ok[:-1]
    seglen = jnp.where(seg_ok, jnp.sqrt(dx * dx + dy * dy), 0.0)
    sigma = jnp.concatenate([jnp.zeros_like(seglen[:1]), jnp.cumsum(seglen, axis=0)])
    phi = jnp.unwrap(jnp.arctan2(dy, dx), axis=0)
    held = jnp.take_along_axis(phi, jnp.maximum(n - 2, 0)[None], axis=0)  # the last chord's direction
    phi = jnp.where(seg_ok, phi, held)
    theta = jnp.concatenate([phi[:1], 0.5 * (phi[1:] + phi[:-1]), phi[-1:]])
    route_s = frenet_points(scene.route, x, y)[0]
    return LanePaths(x, y, ok, sigma, theta, route_s, n)


def frenet_near(ref, xy, s, steps: int = 3):
    """Frenet ``(s, l)`` ``(..., 2)`` of points ``xy (..., 2)`` on the route ``ref``, by Newton steps
    on ``<p - pos(s), tangent(s)> = 0`` from the guesses ``s (...)`` (``to_frenet``'s fixed point
    near the guess, at ``O(log R)`` per point instead of ``O(R)``)."""
    for _ in range(steps):
        pos, th, kap, _ = ref_state(ref, s)
        r = xy - pos
        c, sn = jnp.cos(th), jnp.sin(th)
        along = r[..., 0] * c + r[..., 1] * sn
        lat = c * r[..., 1] - sn * r[..., 0]
        s = s + jnp.clip(along / jnp.maximum(1.0 - kap * lat, 0.2), -50.0, 50.0)
    pos, th, _, _ = ref_state(ref, s)
    r = xy - pos
    return jnp.stack([s, jnp.cos(th) * r[..., 1] - jnp.sin(th) * r[..., 0]], -1)


def with_predictions(scene, step, boxes, valid, sl, length: int):
    """The planner's view: ``scene`` with its obstacles replaced by predictions ``boxes (K, H, 5)``,
    ``valid (K, H)`` and Frenet ``sl (K, H, 2)`` at steps ``[step, step + H)`` of a recording of
    ``length`` steps (``>= step + H``), empty elsewhere; static flags and types kept."""
    K, H = valid.shape
    f = boxes.dtype
    b = lax.dynamic_update_slice(jnp.zeros((K, length, 5), f).at[..., 2:4].set(1.0), boxes, (0, step, 0))
    v = lax.dynamic_update_slice(jnp.zeros((K, length), bool), valid, (0, step))
    s = lax.dynamic_update_slice(jnp.zeros((K, length, 2), f), sl.astype(f), (0, step, 0))
    t = jnp.arange(length, dtype=f) * jnp.asarray(scene.dt, f)
    return dataclasses.replace(scene, obstacles=Obstacles(b, v, t, scene.obstacles.static), obstacle_sl=s)


def anchored_predictions(scene, paths: AgentPaths, state: AgentState, step, H: int):
    """Re-anchored recorded futures of IDM agents (see the module docstring).

    Returns:
        (boxes ``(K, H, 5)``, valid ``(K, H)``, Frenet ``(K, H, 2)``).
    """
    T = paths.s.shape[1]
    k = step + jnp.arange(H)
    kc = jnp.clip(k, 0, T - 1)
    s_now = jnp.take(paths.s, jnp.clip(step, 0, T - 1), axis=1)
    s = state.s[:, None] + jnp.take(paths.s, kc, axis=1) - s_now[:, None]  # (K, H)
    xy, hd, i, fr, past = path_pose(paths, s)
    size = jnp.broadcast_to(paths.box0[:, None, 2:4], xy.shape)
    dyn = jnp.concatenate([xy, size, hd[..., None]], -1)
    valid = jnp.take(paths.valid, kc, axis=1) & (k < T)[None]
    sl = path_frenet(paths, i, fr, past)
    rec = scene.obstacles.window(step, H)
    rec_sl = scene.obstacles.window_of(scene.obstacle_sl, step, H)
    st = paths.static
    return (
        jnp.where(st[:, None, None], rec.boxes, dyn),
        jnp.where(st[:, None], rec.valid, valid),
        jnp.where(st[:, None, None], rec_sl, sl),
    )


def present_state(
    scene, step, paths: AgentPaths | None = None, state: AgentState | None = None
) -> tuple[Any, Any, Any, Any]:
    """Each obstacle now: box ``(K, 5)``, speed ``(K,)``, present ``(K,)``, Frenet ``(K, 2)``.

    With ``paths`` and ``state`` (IDM agents) the simulated agents, else the recording at
    ``step``: the speed is its last step's displacement along its heading (the next step's
    at its first recorded step), never negative."""
    if paths is not None:
        if state is None:
            raise ValueError("present_state: IDM agents (paths) need their state")
        boxes, present = agent_boxes(paths, state, step)
        _, _, i, fr, past = path_pose(paths, state.s)
        sl = path_frenet(paths, i, fr, past)
        v = jnp.where(paths.static, 0.0, state.v)
        return boxes, v, present, sl
    w = scene.obstacles.window(step - 1, 3)  # previous, now, next
    b = w.boxes
    u = jnp.stack([jnp.cos(b[:, 1, 4]), jnp.sin(b[:, 1, 4])], -1)
    dt = jnp.asarray(scene.dt, b.dtype)
    back = jnp.sum((b[:, 1, :2] - b[:, 0, :2]) * u, -1) / dt
    fwd = jnp.sum((b[:, 2, :2] - b[:, 1, :2]) * u, -1) / dt
    v = jnp.where(w.valid[:, 0] & w.valid[:, 1], back, jnp.where(w.valid[:, 1] & w.valid[:, 2], fwd, 0.0))
    v = jnp.where(w.static, 0.0, jnp.maximum(v, 0.0))
    sl = scene.obstacles.window_of(scene.obstacle_sl, step, 1)[:, 0]
    return b[:, 1], v, w.valid[:, 1], sl


def _match_one(lanes: LanePaths, cx, cy, h):
    """The lane path of an obstacle at ``(cx, cy)`` heading ``h``: (path index ``()``, arc length
    of its projection ``()``, signed offset ``()``, found ``()``)."""
    d2 = jnp.where(lanes.valid, jnp.square(lanes.x - cx) + jnp.square(lanes.y - cy), jnp.inf)  # (Q, LP)
    j = jnp.argmin(d2, axis=0)  # (LP,) nearest point of each path
    last_seg = jnp.maximum(lanes.n - 2, 0)
    at = lambda a, g: jnp.take_along_axis(a, g[None], axis=0)[0]  # noqa: E731

    def on_seg(g):  # project onto segment g (LP,) of each path; extended before the first and past the last
        ax, ay = at(lanes.x, g), at(lanes.y, g)
        dx, dy = at(lanes.x, g + 1) - ax, at(lanes.y, g + 1) - ay
        L = jnp.maximum(jnp.sqrt(dx * dx + dy * dy), 1e-6)
        ux, uy = dx / L, dy / L
        u = (cx - ax) * ux + (cy - ay) * uy
        u = jnp.clip(u, jnp.where(g == 0, -jnp.inf, 0.0), jnp.where(g >= last_seg, jnp.inf, L))
        ox, oy = cx - ax - u * ux, cy - ay - u * uy
        lat = ux * oy - uy * ox
        return jnp.sqrt(ox * ox + oy * oy), lat, at(lanes.sigma, g) + u, ux * jnp.cos(h) + uy * jnp.sin(h)

    g0, g1 = jnp.clip(j - 1, 0, last_seg), jnp.clip(j, 0, last_seg)
    r0, r1 = on_seg(g0), on_seg(g1)
    first = r0[0] <= r1[0]
    dist, lat, sig, cos_h = (jnp.where(first, a0, a1) for a0, a1 in zip(r0, r1))
    end = at(lanes.sigma, jnp.maximum(lanes.n - 1, 0))
    ok = (
        (lanes.n >= 2)
        & (dist < LANE_MATCH_DIST)
        & (cos_h > math.cos(LANE_MATCH_ANGLE))
        & (sig > -1.0)
        & (sig < end + 1.0)
    )
    score = jnp.where(ok, dist + LANE_MATCH_TIE * jnp.maximum(sig, 0.0), jnp.inf)
    p = jnp.argmin(score)
    return p, sig[p], lat[p], ok[p]


def _along_path(x, y, theta, sigma, n, q):
    """Point ``(..., 2)`` and direction ``(...)`` at arc lengths ``q (...)`` of one lane path
    (``x, y, theta, sigma (Q,)``, ``n`` valid points), straight on past its last point."""
    Q = x.shape[0]
    last = jnp.maximum(n - 1, 0)
    end = sigma[last]
    sig = jnp.where(jnp.arange(Q) <= last, sigma, end + 1.0 + jnp.arange(Q))  # increasing for the search
    i = jnp.clip(jnp.searchsorted(sig, q, side="right") - 1, 0, jnp.maximum(last - 1, 0))
    seg = jnp.maximum(sig[i + 1] - sig[i], 1e-9)
    f = jnp.clip((q - sig[i]) / seg, 0.0, 1.0)
    px, py = x[i] + f * (x[i + 1] - x[i]), y[i] + f * (y[i + 1] - y[i])
    th = theta[i] + f * (theta[i + 1] - theta[i])
    inside = q <= end
    past = jnp.maximum(q - end, 0.0)
    th_end = theta[last]
    px = jnp.where(inside, px, x[last] + past * jnp.cos(th_end))
    py = jnp.where(inside, py, y[last] + past * jnp.sin(th_end))
    return jnp.stack([px, py], -1), jnp.where(inside, th, th_end)


def cv_predictions(scene, lanes: LanePaths | None, boxes, v, present, sl, H: int):
    """Constant-speed predictions along lanes (see the module docstring) of obstacles now at
    ``boxes (K, 5)`` with speeds ``v (K,)``, presence ``present (K,)`` and Frenet ``sl (K, 2)``.

    Returns:
        (boxes ``(K, H, 5)``, valid ``(K, H)``, Frenet ``(K, H, 2)``); index 0 is the present.
    """
    f = boxes.dtype
    K = boxes.shape[0]
    tau = jnp.arange(H, dtype=f) * jnp.asarray(scene.dt, f)
    d = v[:, None] * tau[None]  # (K, H) distance travelled
    h0 = boxes[:, 4]
    c0 = boxes[:, :2]
    u0 = jnp.stack([jnp.cos(h0), jnp.sin(h0)], -1)
    xy = c0[:, None] + d[..., None] * u0[:, None]
    hd = jnp.broadcast_to(h0[:, None], d.shape)
    _, th_r, _, _ = ref_state(scene.route, sl[:, 0])
    guess = sl[:, :1] + d * jnp.cos(h0 - th_r)[:, None]
    if lanes is not None:
        p, sig0, lat0, found = jax.vmap(lambda c, h: _match_one(lanes, c[0], c[1], h))(c0, h0)
        pick = lambda a: jnp.swapaxes(a[:, p], 0, 1)  # noqa: E731  (K, Q): each obstacle's path
        lx, ly, lth, lsig, ls = (pick(a) for a in (lanes.x, lanes.y, lanes.theta, lanes.sigma, lanes.route_s))
        ln = lanes.n[p]
        q = sig0[:, None] + d
        pl, thl = jax.vmap(_along_path)(lx, ly, lth, lsig, ln, q)
        pl = pl + lat0[:, None, None] * jnp.stack([-jnp.sin(thl), jnp.cos(thl)], -1)
        end = jnp.take_along_axis(lsig, jnp.maximum(ln - 1, 0)[:, None], axis=1)
        g_lane = jax.vmap(jnp.interp)(jnp.minimum(q, end), lsig, ls) + jnp.maximum(q - end, 0.0)
        use = found & (scene.obstacle_type != PEDESTRIAN) & ~scene.obstacles.static
        xy = jnp.where(use[:, None, None], pl, xy)
        hd = jnp.where(use[:, None], thl, hd)
        guess = jnp.where(use[:, None], g_lane, guess)
    sl_pred = frenet_near(scene.route, xy, guess)
    out = jnp.concatenate([xy, jnp.broadcast_to(boxes[:, None, 2:4], (K, H, 2)), hd[..., None]], -1)
    # index 0 is the present exactly; static obstacles hold their box
    out = out.at[:, 0].set(boxes)
    sl_pred = sl_pred.at[:, 0].set(sl)
    st = scene.obstacles.static
    out = jnp.where(st[:, None, None], boxes[:, None], out)
    sl_pred = jnp.where(st[:, None, None], sl[:, None], sl_pred)
    return out, jnp.broadcast_to(present[:, None], (K, H)), sl_pred


def planner_view(
    scene,
    step,
    H: int,
    length: int,
    prediction: str,
    paths: AgentPaths | None = None,
    state: AgentState | None = None,
    lanes: LanePaths | None = None,
):
    """The scene the planner sees at ``step`` (see the module docstring): ``scene`` itself for
    ``oracle`` predictions of recorded traffic (``paths`` None), else a view of ``length`` steps.

    Args:
        scene: one ``Scene``.
        step: ``()`` int, the cycle's step.
        H: the planner's horizon (steps).
        length: steps of the view (at least ``step + H``).
        prediction: ``"oracle"`` or ``"cv"``.
        paths, state: the IDM agents (None: recorded traffic).
        lanes: ``lane_cache(scene)`` for ``cv``.
    """
    if prediction == "oracle":
        if paths is None:
            return scene
        if state is None:
            raise ValueError("planner_view: IDM agents (paths) need their state")
        boxes, valid, sl = anchored_predictions(scene, paths, state, step, H)
    elif prediction == "cv":
        now = present_state(scene, step, paths, state)
        boxes, valid, sl = cv_predictions(scene, lanes, *now, H)
    else:
        raise ValueError(f"prediction must be one of {', '.join(PREDICTIONS)}, got {prediction!r}")
    return with_predictions(scene, step, boxes, valid, sl, length)
