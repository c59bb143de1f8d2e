"""Suite ``speed``: ST-graph speed planning in a closed loop, with and without non-blocking boundaries.

Each scene is driven for ``T_SIM`` seconds: every ``dt`` (1 s) the planner replans
over a 7 s horizon from the car's current state with perfect predictions of the
(non-reactive) obstacles, and the car follows the composed trajectory exactly until
the next replan. Two variants share everything except the weights of the
non-blocking boundaries (no-bypass, blind zone, keep-clear), which are zero in
"without". Metrics are measured on the driven trajectory with the geometry core,
independently of the planner's own station model:

* collisions: scenes where the car's box overlaps an obstacle's box (no buffer);
* blind-zone seconds: time the car's box overlaps a moving obstacle's blind zone
  (beside it, from ``blind_back`` behind its rear to ``blind_front`` ahead of it,
  from 0.5 m off its side, 3 m wide);
* forbidden overtakes: obstacles the planner decided not to bypass whose front the
  car's front passed (along the obstacle's heading);
* keep-clear seconds: time inside a keep-clear region slower than ``keep_clear_v``;
* max jerk of the driven profile, time to reach the goal (``GOAL`` m along the path).

Synthetic scenes: lead vehicle braking, cut-in, neighbour alongside (left, must not be
passed on the right), neighbour's blind zone (truck on the right), keep-clear region
before a queue, crossing pedestrian. ``--scenarios DIR`` adds recorded traffic
(shared JSON format), driven for the length of each recording.
"""
from __future__ import annotations

import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.eval.registry import SuiteArgs, register
from jaxplan.geometry.boxes import box_corners, box_has_overlap, poses_to_boxes
from jaxplan.geometry.frenet import ref_state, reference_line, to_frenet
from jaxplan.geometry.polygons import has_overlap
from jaxplan.speed import CostWeights, SpeedConfig, compose_plan, plan_speed
from jaxplan.speed.nonblocking import obstacle_speed
from jaxplan.types import Obstacles, VehicleParams, at_times_jit

CAR = VehicleParams()
DT_OBS = 0.1
GOAL = 150.0
KINDS = ("lead_braking", "cut_in", "neighbour_alongside", "blind_zone", "keep_clear", "crossing_pedestrian")
K_MAX = 3
R_MAX = 1


@dataclasses.dataclass
class Scenes:
    """A batch of B scenes on a common global time grid ``tg`` (G,)."""

    kind: list
    ref_xy: np.ndarray     # (B, P, 2)
    s0: np.ndarray         # (B,)
    v0: np.ndarray         # (B,)
    v_cruise: np.ndarray   # (B,)
    boxes: np.ndarray      # (B, K, G, 5)
    valid: np.ndarray      # (B, K, G)
    kc: np.ndarray         # (B, R, 4, 2)
    kc_active: np.ndarray  # (B, R)
    goal: np.ndarray       # (B,) distance along the path
    t_sim: float
    static: np.ndarray | None = None  # (B, K) static obstacles (held at every time); None: none
    skipped_files: int = 0  # recorded scenes: files that did not load (named on stderr)

    def obstacle_static(self) -> np.ndarray:
        return np.zeros(self.boxes.shape[:2], bool) if self.static is None else self.static


def _track(x0, v_of_t, tg):
    """Positions of a 1-D motion with speed v(t), integrated on tg."""
    v = np.maximum(v_of_t(tg), 0.0)
    return x0 + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(tg))]), v


def synthetic_scenes(rng, n_per_kind: int, t_sim: float, horizon: float) -> Scenes:
    tg = np.arange(0.0, t_sim + horizon + 1e-6, DT_OBS)
    G = len(tg)
    kinds, boxes, valid, kcs, kca, v0s = [], [], [], [], [], []
    for kind in KINDS:
        for _ in range(n_per_kind):
            b = np.zeros((K_MAX, G, 5))
            b[..., 2:4] = 1.0
            ok = np.zeros((K_MAX, G), bool)
            kc = np.tile(np.array([[0.0, -1], [1, -1], [1, 1], [0, 1]]), (R_MAX, 1, 1)) + 1000.0
            kc_on = np.zeros(R_MAX, bool)
            v0 = rng.uniform(9.0, 12.0)

            def put(k, x, y, L, W, h=0.0):
                b[k, :, 0], b[k, :, 1], b[k, :, 2], b[k, :, 3], b[k, :, 4] = x, y, L, W, h
                ok[k] = True

            if kind == "lead_braking":
                vl, tb, dec, vend = rng.uniform(10, 12), rng.uniform(1, 3), rng.uniform(3, 5), rng.uniform(2, 5)
                x, _ = _track(rng.uniform(22, 32), lambda t: np.where(t < tb, vl, np.maximum(vl - dec * (t - tb), vend)), tg)
                put(0, x, 0.0, 4.5, 1.8)
            elif kind == "cut_in":
                vc, tc, dur = rng.uniform(7, 9), rng.uniform(0.5, 2.0), 2.5
                x, _ = _track(rng.uniform(6, 14), lambda t: vc + 0 * t, tg)
                y = 3.5 * (1 - np.clip((tg - tc) / dur, 0, 1))
                h = np.where((tg > tc) & (tg < tc + dur), -np.arctan2(3.5 / dur, vc), 0.0)
                put(0, x, y, 4.5, 1.8, h)
            elif kind == "neighbour_alongside":
                vn = rng.uniform(6, 9)
                x, _ = _track(rng.uniform(6, 14), lambda t: vn + 0 * t, tg)
                put(0, x, 3.5, 4.6, 1.8)
            elif kind == "blind_zone":
                vt = rng.uniform(10.5, 12.5)
                x, _ = _track(rng.uniform(7, 11), lambda t: vt + 0 * t, tg)
                put(0, x, -3.5, 12.0, 2.5)
            elif kind == "keep_clear":
                xr = rng.uniform(26, 32)
                kc[0] = [[xr, -2.5], [xr + 8, -2.5], [xr + 8, 2.5], [xr, 2.5]]
                kc_on[0] = True
                tgo = rng.uniform(9, 12)
                x, _ = _track(xr + 8 + rng.uniform(6, 9), lambda t: np.clip(1.5 * (t - tgo), 0, 10), tg)
                put(0, x, 0.0, 4.5, 1.8)
                x2, _ = _track(x[0] + 7, lambda t: np.clip(1.5 * (t - tgo + 0.5), 0, 10), tg)
                put(1, x2, 0.0, 4.5, 1.8)
            elif kind == "crossing_pedestrian":
                vy = rng.uniform(1.0, 1.6)
                put(0, rng.uniform(32, 45), -7.0 + vy * tg, 0.6, 0.6, np.pi / 2)
            kinds.append(kind)
            boxes.append(b)
            valid.append(ok)
            kcs.append(kc)
            kca.append(kc_on)
            v0s.append(v0)
    B = len(kinds)
    ref = np.stack([np.linspace(-20.0, 400.0, 8), np.zeros(8)], -1)
    return Scenes(kinds, np.repeat(ref[None], B, 0), np.full(B, 20.0), np.array(v0s), np.full(B, 12.0),
                  np.array(boxes), np.array(valid), np.array(kcs), np.array(kca), np.full(B, GOAL), t_sim)


def recorded_scenes(directory: str, t_max: float, horizon: float, k_max: int = 24, n: int | None = None) -> Scenes:
    """Recorded traffic: the ego lane's centre line as the path, the recording as obstacles
    (read at the suite's 0.1 s grid, static obstacles held over the whole drive)."""
    import sys

    from jaxplan.scenarios.loader import lane_reference, load_folder

    folder = load_folder(directory)
    tg = np.arange(0.0, t_max + horizon + 1e-6, DT_OBS)
    G = len(tg)
    out = dict(kind=[], ref_xy=[], s0=[], v0=[], v_cruise=[], boxes=[], valid=[], static=[], goal=[])
    for f, s in zip(folder.files, folder.scenarios):
        if n is not None and len(out["kind"]) >= n:
            break
        if s.obstacles.boxes.shape[1] <= 10 or s.obstacles.boxes.shape[0] == 0:
            continue  # a recording of 1 s or less, or nobody to meet: nothing to measure
        try:
            ref = lane_reference(s)
        except ValueError as e:
            print(f"jaxplan: speed: no reference line in {f}: {e}", file=sys.stderr)
            continue
        d = np.linalg.norm(np.diff(np.asarray(ref.xy), axis=0), axis=1)
        u = np.concatenate([[0.0], np.cumsum(d)])
        q = np.linspace(0, u[-1], 64)
        xy = np.stack([np.interp(q, u, np.asarray(ref.xy)[:, i]) for i in range(2)], -1)
        s0, _ = to_frenet(reference_line(jnp.asarray(xy, jnp.float32)), jnp.zeros((1, 2)))
        ob = at_times_jit(s.obstacles, jnp.asarray(tg, s.obstacles.boxes.dtype))
        b = np.asarray(ob.boxes, float)
        ok = np.asarray(ob.valid)
        dist = np.where(ok[:, 0], np.linalg.norm(b[:, 0, :2], axis=-1), 1e9)
        keep = np.argsort(dist)[:k_max]
        bb = np.zeros((k_max, G, 5))
        bb[..., 2:4] = 1.0
        vv = np.zeros((k_max, G), bool)
        ss = np.zeros(k_max, bool)
        bb[:len(keep)], vv[:len(keep)], ss[:len(keep)] = b[keep], ok[keep], np.asarray(ob.static)[keep]
        out["kind"].append("recorded:" + s.id)
        out["ref_xy"].append(xy)
        out["s0"].append(float(s0[0]))
        out["v0"].append(s.ego.v)
        out["v_cruise"].append(max(s.ego.v, 8.0))
        out["boxes"].append(bb)
        out["valid"].append(vv)
        out["static"].append(ss)
        out["goal"].append(max(s.ego.v, 8.0) * (s.obstacles.boxes.shape[1] - 1) * s.dt * 0.8)
    B = len(out["kind"])
    kc = np.tile(np.array([[0.0, -1], [1, -1], [1, 1], [0, 1]]) + 1000.0, (B, R_MAX, 1, 1))
    return Scenes(out["kind"], np.array(out["ref_xy"]), np.array(out["s0"]), np.array(out["v0"]),
                  np.array(out["v_cruise"]), np.array(out["boxes"]), np.array(out["valid"]), kc,
                  np.zeros((B, R_MAX), bool), np.array(out["goal"]), t_max, np.array(out["static"], bool).reshape(B, k_max),
                  len(folder.skipped))


def _weights(sc: Scenes, with_nb: bool):
    w = CostWeights.default()
    v = jnp.asarray(sc.v_cruise, jnp.float32)
    w = dataclasses.replace(w, v_cruise=v)
    if not with_nb:
        z = jnp.zeros_like(v)
        w = dataclasses.replace(w, w_no_bypass=z, w_blind=z, w_keep_clear=z)
    return w


def _compose_batch(cfg: SpeedConfig, n_out: int):
    def one(ref, s0, plan, v0):
        return compose_plan(ref, s0, plan, v0, DT_OBS, n_out)

    return jax.jit(jax.vmap(one))


def _smooth_batch(cfg: SpeedConfig):
    from jaxplan.speed.smooth import smooth_plan

    def one(plan, v0):
        t, s, _, _, ok = smooth_plan(plan, v0, cfg)
        return t, s, ok

    return jax.jit(jax.vmap(one))


def simulate(sc: Scenes, cfg: SpeedConfig, with_nb: bool, smooth: bool = False):
    """Closed loop. Returns driven s, v, a ``(B, S)`` at DT_OBS, no-bypass flags ``(B, K)``,
    the first plans and the first scenes' classification."""
    B = len(sc.kind)
    refs = jax.vmap(reference_line)(jnp.asarray(sc.ref_xy, jnp.float32))
    w = _weights(sc, with_nb)
    n_rep = int(round(sc.t_sim / cfg.dt))
    per = int(round(cfg.dt / DT_OBS))
    n_pred = int(round(cfg.horizon / DT_OBS)) + 1
    compose = _compose_batch(cfg, per + 1)
    smoother = _smooth_batch(cfg) if smooth else None
    s = jnp.asarray(sc.s0, jnp.float32)
    v = jnp.asarray(sc.v0, jnp.float32)
    a = jnp.zeros(B, jnp.float32)
    kc = (jnp.asarray(sc.kc, jnp.float32), jnp.ones(sc.kc.shape[:-1], bool), jnp.asarray(sc.kc_active))
    tp = jnp.asarray(np.arange(n_pred) * DT_OBS, jnp.float32)
    S, V, A = [np.asarray(s)[:, None]], [np.asarray(v)[:, None]], [np.asarray(a)[:, None]]
    no_bypass = np.zeros(sc.valid.shape[:2], bool)
    first = None
    for r in range(n_rep):
        g = r * per
        obs = Obstacles(jnp.asarray(sc.boxes[:, :, g:g + n_pred], jnp.float32),
                        jnp.asarray(sc.valid[:, :, g:g + n_pred]), jnp.broadcast_to(tp, (B, n_pred)),
                        jnp.asarray(sc.obstacle_static()))
        plan = plan_speed(refs, obs, cfg, w, v0=v, a0=a, s0=s, keep_clear=kc, vehicle=CAR)
        no_bypass |= np.asarray(plan.scene.classified.no_bypass)
        if first is None:
            first = plan
        if smooth:  # execute the smoothing QP's profile (where it is feasible)
            ts, ss, ok = smoother(plan, v)
            qp_plan = dataclasses.replace(plan, t=ts, s=ss, scene=None)
            tr_qp = compose(refs, s, qp_plan, v)
            tr_dp = compose(refs, s, plan, v)
            tr = jax.tree_util.tree_map(lambda x, y: jnp.where(ok[:, None], x, y), tr_qp, tr_dp)
        else:
            tr = compose(refs, s, plan, v)
        S.append(np.asarray(s)[:, None] + np.asarray(tr.s)[:, 1:])
        V.append(np.asarray(tr.v)[:, 1:])
        A.append(np.asarray(tr.a)[:, 1:])
        s, v, a = s + tr.s[:, -1], tr.v[:, -1], tr.a[:, -1]
    return np.concatenate(S, 1), np.concatenate(V, 1), np.concatenate(A, 1), no_bypass, first


@jax.jit
def _geometry_metrics(ref_xy, s, v, boxes, valid, kc, kc_active, speeds, blind_back, blind_front):
    """Per scene: collision (S,), blind-zone flags (S,), keep-clear-stop flags (S,), front overtakes (K, S)."""

    def one(ref_xy, s, v, boxes, valid, kc, kc_active, speeds):
        ref = reference_line(ref_xy)
        xy, th, _, _ = ref_state(ref, s)
        ego = poses_to_boxes(xy, th, CAR)  # (S, 5)
        ob = boxes[:, : s.shape[0]]  # (K, S, 5)
        ok = valid[:, : s.shape[0]]
        col = jnp.any(box_has_overlap(ego, ob) & ok, 0)
        # blind zones: beside each moving obstacle, from blind_back behind its rear to blind_front ahead of it
        L, W, h = ob[..., 2], ob[..., 3], ob[..., 4]
        c, sn = jnp.cos(h), jnp.sin(h)
        lon = -0.5 * L + 0.5 * (blind_front - blind_back)
        zl = blind_back + blind_front
        zones = []
        for side in (1.0, -1.0):
            lat = side * (0.5 * W + 0.5 + 1.5)
            cx = ob[..., 0] + c * lon - sn * lat
            cy = ob[..., 1] + sn * lon + c * lat
            zones.append(jnp.stack([cx, cy, jnp.broadcast_to(zl, cx.shape), jnp.full_like(cx, 3.0), h], -1))
        in_zone = (box_has_overlap(ego, zones[0]) | box_has_overlap(ego, zones[1])) & ok & (speeds[:, None] > 1.0)
        blind = jnp.any(in_zone, 0)
        corners = box_corners(ego)  # (S, 4, 2)
        in_kc = has_overlap(corners, kc[:, None]) & kc_active[:, None]  # (R, S)
        kc_stop = jnp.any(in_kc, 0) & (v < 1.0)
        # obstacle frame: car front minus obstacle front along the obstacle heading
        front = xy + (CAR.center_offset + 0.5 * CAR.length) * jnp.stack([jnp.cos(th), jnp.sin(th)], -1)
        ofront = ob[..., :2] + 0.5 * L[..., None] * jnp.stack([c, sn], -1)
        ahead = jnp.sum((front - ofront) * jnp.stack([c, sn], -1), -1) > 0  # (K, S)
        return col, blind, kc_stop, ahead & ok

    return jax.vmap(one)(ref_xy, s, v, boxes, valid, kc, kc_active, speeds)


def measure(sc: Scenes, s, v, a, no_bypass, cfg: SpeedConfig) -> dict:
    n = s.shape[1]
    spd = np.asarray(obstacle_speed(Obstacles(jnp.asarray(sc.boxes, jnp.float32), jnp.asarray(sc.valid),
                                              jnp.asarray(np.arange(sc.boxes.shape[2]) * DT_OBS, jnp.float32),
                                              jnp.asarray(sc.obstacle_static()))))
    col, blind, kc_stop, ahead = (np.asarray(x) for x in _geometry_metrics(
        jnp.asarray(sc.ref_xy, jnp.float32), jnp.asarray(s, jnp.float32), jnp.asarray(v, jnp.float32),
        jnp.asarray(sc.boxes, jnp.float32),
        jnp.asarray(sc.valid), jnp.asarray(sc.kc, jnp.float32), jnp.asarray(sc.kc_active),
        jnp.asarray(spd, jnp.float32), cfg.blind_back, cfg.blind_front))
    ok = sc.valid[:, :, :n]
    first_ok = np.argmax(ok, -1)
    behind0 = ~np.take_along_axis(ahead, first_ok[..., None], -1)[..., 0]
    overtook = behind0 & np.any(ahead & ok, -1) & no_bypass  # (B, K)
    travelled = s - s[:, :1]
    reached = travelled[:, -1] >= sc.goal
    t_goal = np.where(reached, np.argmax(travelled >= sc.goal[:, None], -1) * DT_OBS, np.nan)
    jerk = np.abs(np.diff(a, axis=1)) / DT_OBS
    return {"collision": col.any(-1), "blind_s": blind.sum(-1) * DT_OBS, "keep_clear_s": kc_stop.sum(-1) * DT_OBS,
            "forbidden_overtakes": overtook.sum(-1), "max_jerk": jerk.max(-1), "t_goal": t_goal,
            "progress": travelled[:, -1], "t_sim": (n - 1) * DT_OBS}


def _summary(prefix, mw, mo, kinds) -> dict:
    out = {}
    for tag, m in (("with", mw), ("without", mo)):
        out[f"{prefix}{tag}.collisions"] = int(m["collision"].sum())
        out[f"{prefix}{tag}.blind_zone_s"] = round(float(m["blind_s"].sum()), 2)
        out[f"{prefix}{tag}.keep_clear_s"] = round(float(m["keep_clear_s"].sum()), 2)
        out[f"{prefix}{tag}.forbidden_overtakes"] = int(m["forbidden_overtakes"].sum())
        out[f"{prefix}{tag}.max_jerk_mean"] = round(float(m["max_jerk"].mean()), 2)
        out[f"{prefix}{tag}.progress_mean_m"] = round(float(m["progress"].mean()), 2)
    both = ~np.isnan(mw["t_goal"]) & ~np.isnan(mo["t_goal"])
    out[f"{prefix}reached_goal_both"] = int(both.sum())
    out[f"{prefix}reached_goal_with"] = int((~np.isnan(mw["t_goal"])).sum())
    out[f"{prefix}reached_goal_without"] = int((~np.isnan(mo["t_goal"])).sum())
    # censored: a scene that does not reach the goal counts t_sim (a lower bound of its time)
    tw_all = np.where(np.isnan(mw["t_goal"]), mw["t_sim"], mw["t_goal"]).mean()
    to_all = np.where(np.isnan(mo["t_goal"]), mo["t_sim"], mo["t_goal"]).mean()
    out[f"{prefix}travel_time_ratio_all_censored"] = round(float(tw_all / to_all), 4)
    if both.any():
        tw, to = float(mw["t_goal"][both].mean()), float(mo["t_goal"][both].mean())
        out[f"{prefix}with.time_to_goal_s"] = round(tw, 3)
        out[f"{prefix}without.time_to_goal_s"] = round(to, 3)
        out[f"{prefix}travel_time_ratio"] = round(tw / to, 4)
    bo = float(mo["blind_s"].sum())
    out[f"{prefix}blind_zone_reduction"] = round(1 - float(mw["blind_s"].sum()) / bo, 4) if bo > 0 else float("nan")
    kinds = np.array([k.split(":")[0] for k in kinds])
    for k in np.unique(kinds):
        sel = kinds == k
        for tag, m in (("with", mw), ("without", mo)):
            out[f"{prefix}{k}.{tag}.blind_zone_s"] = round(float(m["blind_s"][sel].sum()), 2)
            out[f"{prefix}{k}.{tag}.collisions"] = int(m["collision"][sel].sum())
            out[f"{prefix}{k}.{tag}.forbidden_overtakes"] = int(m["forbidden_overtakes"][sel].sum())
            out[f"{prefix}{k}.{tag}.keep_clear_s"] = round(float(m["keep_clear_s"][sel].sum()), 2)
    return out


def _claim(prefix, m) -> dict:
    red = m.get(f"{prefix}blind_zone_reduction", float("nan"))
    ratio = m.get(f"{prefix}travel_time_ratio", float("nan"))
    holds = (red >= 0.5 and m[f"{prefix}with.forbidden_overtakes"] == 0
             and m[f"{prefix}with.collisions"] <= m[f"{prefix}without.collisions"] and ratio <= 1.10)
    return {f"{prefix}claim_holds": int(bool(holds))}


def _plot_st(sc: Scenes, first_with, first_without, cfg: SpeedConfig, out: str, idxs):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plan_w, plan_o = first_with, first_without
    c = plan_w.scene.classified
    kc = plan_w.scene
    tf = cfg.fine_times()
    front = CAR.center_offset + 0.5 * CAR.length
    rear = CAR.center_offset - 0.5 * CAR.length
    fig, axes = plt.subplots(1, len(idxs), figsize=(4.2 * len(idxs), 4), squeeze=False)
    for ax, b in zip(axes[0], idxs):
        for k in range(c.blocking.hit.shape[1]):
            hit = np.asarray(c.blocking.hit[b, k])
            if hit.any():
                lo, hi = np.asarray(c.blocking.lower[b, k]), np.asarray(c.blocking.upper[b, k])
                ax.fill_between(tf, np.where(hit, lo, np.nan), np.where(hit, hi, np.nan), color="tab:red",
                                alpha=0.5, label="blocking" if k == 0 else None)
            hit = np.asarray(c.side.hit[b, k])
            if hit.any():
                lo, hi = np.asarray(c.side.lower[b, k]), np.asarray(c.side.upper[b, k])
                ax.fill_between(tf, np.where(hit, lo - front, np.nan), np.where(hit, hi - rear, np.nan),
                                color="tab:blue", alpha=0.3, label="non-blocking (alongside)")
                ax.fill_between(tf, np.where(hit, lo - cfg.blind_back - front, np.nan),
                                np.where(hit, lo + cfg.blind_front - rear, np.nan), color="tab:cyan", alpha=0.3,
                                hatch="//", label="blind zone")
        for r in range(kc.kc_hit.shape[1]):
            if bool(kc.kc_hit[b, r]):
                ax.axhspan(float(kc.kc_lower[b, r]), float(kc.kc_upper[b, r]), color="tab:green", alpha=0.25,
                           label="keep-clear region")
        ax.plot(np.asarray(plan_w.t[b]), np.asarray(plan_w.s[b]), "k-o", ms=3, label="plan with non-blocking")
        ax.plot(np.asarray(plan_o.t[b]), np.asarray(plan_o.s[b]), "--", color="tab:orange", marker="s", ms=3,
                label="plan without")
        ax.set_title(sc.kind[b])
        ax.set_xlabel("t (s)")
        ax.set_ylabel("s (m, car reference point)")
        ax.set_ylim(-2, max(60, float(np.asarray(plan_w.s[b]).max()) + 10))
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "speed_st_graph.png"), dpi=90)
    plt.close(fig)


def _plot_profiles(sc, res_w, res_o, out):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(12, 6))
    for ax, kind in zip(axes.ravel(), KINDS):
        b = sc.kind.index(kind)
        t = np.arange(res_w[1].shape[1]) * DT_OBS
        ax.plot(t, res_w[1][b], "k", label="with non-blocking")
        ax.plot(t, res_o[1][b], "--", color="tab:orange", label="without")
        ax.set_title(kind)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("v (m/s)")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "speed_profiles.png"), dpi=90)
    plt.close(fig)


def _run(sc: Scenes, cfg: SpeedConfig, prefix: str, smooth: bool = False):
    res_w = simulate(sc, cfg, True)
    res_o = simulate(sc, cfg, False)
    mw = measure(sc, *res_w[:4], cfg)
    mo = measure(sc, *res_o[:4], cfg)
    m = _summary(prefix, mw, mo, sc.kind)
    m.update(_claim(prefix, m))
    m[f"{prefix}scenes"] = len(sc.kind)
    if smooth:  # the same "with" planner executing the smoothing QP's profile
        res_s = simulate(sc, cfg, True, smooth=True)
        ms = measure(sc, *res_s[:4], cfg)
        m[f"{prefix}with_smooth.collisions"] = int(ms["collision"].sum())
        m[f"{prefix}with_smooth.blind_zone_s"] = round(float(ms["blind_s"].sum()), 2)
        m[f"{prefix}with_smooth.forbidden_overtakes"] = int(ms["forbidden_overtakes"].sum())
        m[f"{prefix}with_smooth.keep_clear_s"] = round(float(ms["keep_clear_s"].sum()), 2)
        m[f"{prefix}with_smooth.max_jerk_mean"] = round(float(ms["max_jerk"].mean()), 2)
        m[f"{prefix}with_smooth.progress_mean_m"] = round(float(ms["progress"].mean()), 2)
    return m, res_w, res_o


@register("speed")
def speed_suite(args: SuiteArgs) -> dict:
    rng = np.random.default_rng(args.seed)
    cfg = SpeedConfig()
    n_per = args.n or (3 if args.quick else 16)
    t_sim = 16.0 if args.quick else 20.0
    sc = synthetic_scenes(rng, n_per, t_sim, cfg.horizon)
    m, res_w, res_o = _run(sc, cfg, "", smooth=not args.quick)
    idxs = [sc.kind.index(k) for k in ("neighbour_alongside", "blind_zone", "keep_clear", "crossing_pedestrian")]
    _plot_st(sc, res_w[4], res_o[4], cfg, args.out, idxs)
    _plot_profiles(sc, res_w, res_o, args.out)
    if args.scenarios:
        rcfg = SpeedConfig(v_max=30.0)
        rs = recorded_scenes(args.scenarios, 5.0, rcfg.horizon, n=8 if args.quick else None)
        m["skipped_files"] = rs.skipped_files
        if len(rs.kind):
            mr, _, _ = _run(rs, rcfg, "recorded.")
            m.update({k: v for k, v in mr.items() if k.count(".") <= 2 and "recorded:" not in k})
    return m
