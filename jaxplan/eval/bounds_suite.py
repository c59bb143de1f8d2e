"""Suite ``bounds``: path bounds against the exact bound, and paths planned inside them.

Curved roads (radius 5 ... 80 m and straight), frames of 20 points over 4 s,
obstacles of random size, offset and heading near the path (a third of them
moving along the road), none overlapping the car's first pose. For each bound
method (centre-line baseline, Apollo-style SL box, contour along the Frenet
normal, contour along the trajectory normal, exact): mean / 95th-percentile
``|bound - exact bound|`` per radius over the pairs (point, obstacle) where the
car on the decision trajectory overlaps the obstacle, the share of unsafe bounds
(the car placed at the bound still overlaps), the share more than 0.2 m
over-conservative; the share of frames whose path optimised inside the bounds
(at the decision trajectory's heading, no decision) collides.

The planner's path (``path.*``: ``jaxplan.bounds.path_planner.solve_path`` on a
grid twice as dense as the frame, obstacles at each station's time): side
decisions against the free corridor, buffer, cut at a blockage, bounds recomputed
at the optimised heading; the share of frames with a path, the share blocked, the
QP's success on frames whose corridor is feasible, and the share of solved paths
that collide (SAT at every station and between stations). With ``osqp`` installed
(the test extra), OSQP's verdict on each frame's last path QP: the QP's success on the
frames OSQP solves, and the share it certifies infeasible. Plots: error against
radius; one frame.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.bounds.frenet_bounds import path_bounds
from jaxplan.bounds.optimize import optimize_path
from jaxplan.bounds.path_planner import PathConfig, solve_path
from jaxplan.bounds.path_qp import PathQPConfig, curvature_bounds
from jaxplan.eval.registry import SuiteArgs, register
from jaxplan.geometry import (
    ReferenceLine,
    box_corners,
    has_overlap,
    headings_from_path,
    ref_state,
    reference_line,
    to_cartesian,
    vehicle_corners,
)
from jaxplan.types import VehicleParams

RADII = (5.0, 8.0, 12.0, 20.0, 40.0, 80.0, np.inf)
METHODS = ("centerline", "slbox", "contour", "contour_traj", "exact")
# The car's front reaches 3.68 m ahead of its reference point and an obstacle's half
# diagonal is at most 2.75 m: obstacles start (t = 0) at s >= 9 m, the car at s = 2 m.
OBSTACLE_MIN_S = 9.0
T = 20
HORIZON = 4.0
N_REF = 161
LANE = 5.0  # lane limits on l (m)
CAR = VehicleParams()


def _road(radius, length):
    """Reference polyline ``(N_REF, 2)`` from s = -5 to ``length`` (left turn of ``radius``)."""
    s = np.linspace(-5.0, length, N_REF)
    if np.isinf(radius):
        return np.stack([s, np.zeros_like(s)], -1)
    a = s / radius
    return np.stack([radius * np.sin(a), radius * (1 - np.cos(a))], -1)


def make_scenarios(rng, n_frames, n_obs, radii=RADII):
    """Per radius: reference polylines, decision trajectories, obstacle contours (numpy).

    Returns:
        (refs ``(R, N_REF, 2)``, s ``(R, F, T)``, l ``(R, F, T)``, corners ``(R, F, K, T, 4, 2)``,
        speeds ``(R,)``, boxes ``(R, F, K, T, 5)``).
    """
    refs, S, L, OBS, VEL, BOX = [], [], [], [], [], []
    t = np.linspace(0.0, HORIZON, T)
    for r in radii:
        v = 8.0 if np.isinf(r) else min(8.0, np.sqrt(2.5 * r))
        s_end = 2.0 + v * HORIZON
        refs.append(_road(r, s_end + 10.0))
        s = np.broadcast_to(2.0 + v * t, (n_frames, T))
        l = rng.uniform(-0.3, 0.3, (n_frames, 1)) + rng.uniform(-0.1, 0.1, (n_frames, 1)) * np.sin(t / HORIZON * np.pi)
        ref = ReferenceLine.from_polyline(refs[-1])
        s_o = rng.uniform(OBSTACLE_MIN_S, max(s_end, OBSTACLE_MIN_S + 4.0), (n_frames, n_obs))
        l_o = rng.choice([-1.0, 1.0], (n_frames, n_obs)) * rng.uniform(1.0, 3.2, (n_frames, n_obs))
        moving = rng.uniform(size=(n_frames, n_obs)) < 1 / 3
        v_o = np.where(moving, rng.uniform(0.5, 0.6 * v, (n_frames, n_obs)), 0.0)
        s_ot = s_o[..., None] + v_o[..., None] * t  # (F, K, T), at t = 0 from OBSTACLE_MIN_S on
        xy = np.asarray(
            to_cartesian(
                ref,
                jnp.asarray(s_ot, jnp.float32),
                jnp.asarray(np.broadcast_to(l_o[..., None], s_ot.shape), jnp.float32),
            )
        )
        _, th, _, _ = ref_state(ref, jnp.asarray(s_ot, jnp.float32))
        head = np.asarray(th) + rng.uniform(-0.5, 0.5, (n_frames, n_obs))[..., None]
        size = np.stack([rng.uniform(1.0, 5.0, (n_frames, n_obs)), rng.uniform(0.5, 2.2, (n_frames, n_obs))], -1)
        boxes = np.concatenate([xy, np.broadcast_to(size[..., None, :], s_ot.shape + (2,)), head[..., None]], -1)
        OBS.append(np.asarray(box_corners(jnp.asarray(boxes, jnp.float32))))
        BOX.append(boxes)
        S.append(s)
        L.append(l)
        VEL.append(v)
    return (
        np.stack(refs).astype(np.float32),
        np.stack(S).astype(np.float32),
        np.stack(L).astype(np.float32),
        np.stack(OBS).astype(np.float32),
        np.asarray(VEL),
        np.stack(BOX).astype(np.float32),
    )


def _at_bound(ref, s, l, heading, bound, obs):
    """Whether the car at ``(s, bound)`` (decision heading) overlaps each obstacle. ``(F, T, K)``."""
    _, th, _, _ = ref_state(ref, s)
    n = jnp.stack([-jnp.sin(th), jnp.cos(th)], -1)
    base = to_cartesian(ref, s, jnp.zeros_like(s))
    p = base[..., None, :] + jnp.where(jnp.isfinite(bound), bound, l[..., None])[..., None] * n[..., None, :]
    car = vehicle_corners(p, CAR, jnp.broadcast_to(heading[..., None], bound.shape))
    return has_overlap(car, jnp.swapaxes(obs, -3, -4))


QP = PathQPConfig(jerk_max=0.2)
PATH = PathConfig(vehicle=CAR, lat_buffer=0.3, lon_buffer=0.2, buffer_ramp=2.0)


def densify(x, axis):
    """Insert the midpoint between consecutive entries along ``axis`` (``T -> 2T - 1``)."""
    x = jnp.moveaxis(x, axis, 0)
    mid = 0.5 * (x[1:] + x[:-1])
    out = jnp.concatenate([jnp.stack([x[:-1], mid], 1).reshape((-1,) + x.shape[1:]), x[-1:]], 0)
    return jnp.moveaxis(out, 0, axis)


def frame_path(ref, s, l, boxes):
    """The planner's path for one frame: ``s, l (T,)``, ``boxes (K, T, 5)``."""
    st = densify(s, 0)
    bx = jnp.swapaxes(densify(boxes, 1), 0, 1)  # (N, K, 5)
    N = st.shape[0]
    edge = jnp.full((N,), LANE + 0.5 * CAR.width, st.dtype)
    ds, init = st[1] - st[0], jnp.stack([l[0], 0.0, 0.0]).astype(st.dtype)
    res = solve_path(ref, st, ds, bx, jnp.ones(bx.shape[:2], bool), edge, -edge, jnp.zeros_like(st), init, PATH)
    cor, qp = res["corridor"], res["qp"]
    return dict(
        ok=qp.ok & res["clear"] & (cor.blocked_index > 1),
        qp_ok=qp.ok,
        clear=res["clear"],
        qp_input=jnp.stack(res["qp_input"]),
        init=init,
        ds=ds,
        blocked=cor.blocked_index < N,
        corridor_ok=cor.blocked_index > 1,
        qp_infeasible=~qp.feasible,
        rounds=res["rounds"],
        l=res["l"],
        lower=cor.lower,
        upper=cor.upper,
        valid=cor.valid,
        theta=res["theta"],
        xy=res["xy"],
    )


def _osqp_verdicts(p, corridor_ok, max_iter=20000):
    """OSQP's verdict on each frame's last path QP: ``"solved"``, ``"infeasible"``,
    ``"undecided"`` (its iteration cap), ``""`` where the corridor is closed (the QP's data as
    the planner builds it, in float32, solved in float64 to eps 1e-6); None without ``osqp``
    (a test oracle, not a dependency)."""
    try:
        import osqp
        import scipy.sparse as sp
    except ImportError:
        return None
    from jaxplan.bounds.path_qp import PathWeights, state_problem

    qi = p["qp_input"].reshape((-1,) + p["qp_input"].shape[-2:])
    init, ds, cok = p["init"].reshape(-1, 3), p["ds"].reshape(-1), corridor_ok.reshape(-1)
    out = np.full(cok.shape, "", dtype=object)
    j = lambda a: jnp.asarray(a, jnp.float32)
    for f in np.nonzero(cok)[0]:
        lo_l, up_l, dlo, dhi, ddlo, ddhi = qi[f]
        T = lo_l.shape[0]
        P, q, A, lo, hi = (
            np.asarray(x, np.float64)
            for x in state_problem(
                j(ds[f]),
                jnp.zeros(T, jnp.float32),
                j(lo_l),
                j(up_l),
                j(dlo),
                j(dhi),
                j(ddlo),
                j(ddhi),
                PATH.qp.jerk_max,
                j(init[f]),
                PathWeights(*PATH.weights),
            )
        )
        lo, hi = np.where(np.isfinite(lo), lo, -1e30), np.where(np.isfinite(hi), hi, 1e30)
        if np.any(lo > hi):
            out[f] = "infeasible"
            continue
        m = osqp.OSQP()
        m.setup(
            sp.csc_matrix(np.triu(P)),
            q,
            sp.csc_matrix(A),
            lo,
            hi,
            verbose=False,
            eps_abs=1e-6,
            eps_rel=1e-6,
            max_iter=max_iter,
            polish=True,
        )
        st = m.solve().info.status
        out[f] = "solved" if st == "solved" else "infeasible" if "infeasible" in st else "undecided"
    return out.reshape(corridor_ok.shape)


def _one_radius(ref_xy, s, l, obs, boxes):
    ref = reference_line(ref_xy)
    out = {}
    ds = s[:, 1] - s[:, 0]
    k_max = jnp.tan(CAR.max_steer) / CAR.wheelbase
    _, _, k_r, _ = ref_state(ref, s)
    ddl = curvature_bounds(k_r, k_max)
    bs = {}
    for m in METHODS:
        method = "contour" if m.startswith("contour") else m
        normal = "trajectory" if m == "contour_traj" else "frenet"
        bs[m] = path_bounds(
            ref, s, l, CAR, obs, lane_lower=-LANE, lane_upper=LANE, method=method, normal=normal, rectangles=True
        )
    # One QP call for every method's bounds (one compiled solver).
    M = len(METHODS)
    init = jnp.stack([l[:, 0], jnp.zeros_like(l[:, 0]), jnp.zeros_like(l[:, 0])], -1)
    rep = lambda x: jnp.concatenate([x] * M, 0)
    qp_all = optimize_path(
        jnp.concatenate([bs[m].lower for m in METHODS]),
        jnp.concatenate([bs[m].upper for m in METHODS]),
        rep(ds),
        rep(l),
        rep(init),
        config=QP,
        ddl_bounds=(rep(ddl[0]), rep(ddl[1])),
    )
    F = s.shape[0]
    for j, m in enumerate(METHODS):
        b = bs[m]
        qp = jax.tree_util.tree_map(lambda x: x[j * F : (j + 1) * F], qp_all)
        bound = jnp.where(b.left, b.obstacle_upper, b.obstacle_lower)  # (F, T, K)
        # 1 mm towards the safe side, so that touching is not counted as unsafe.
        safe = jnp.where(b.left, bound - 1e-3, bound + 1e-3)
        unsafe = _at_bound(ref, s, l, b.heading, safe, obs) | ~jnp.isfinite(bound)
        path = to_cartesian(ref, s, jnp.where(qp.ok[:, None], qp.l, l))
        cars = vehicle_corners(path, CAR, headings_from_path(path))  # (F, T, 4, 2)
        hit = has_overlap(cars[:, None], obs)  # (F, K, T)
        out[m] = dict(
            bound=bound,
            unsafe=unsafe,
            overlap=b.overlap,
            left=b.left,
            case=b.case,
            collide=jnp.any(hit, axis=(1, 2)),
            qp_ok=qp.ok,
            qp_feasible=qp.feasible,
            qp_l=qp.l,
            lower=b.lower,
            upper=b.upper,
            heading=b.heading,
        )
    out["path"] = jax.vmap(lambda s1, l1, b1: frame_path(ref, s1, l1, b1))(s, l, boxes)
    return out


_all_radii = jax.jit(jax.vmap(_one_radius))


def _figures(res, radii):
    ex = np.asarray(res["exact"]["bound"])
    ov = np.asarray(res["exact"]["overlap"])
    left = np.asarray(res["exact"]["left"])
    m = {}
    per = {}
    for meth in METHODS:
        r = res[meth]
        b = np.asarray(r["bound"])
        rows = []
        for i, rad in enumerate(radii):
            sel = ov[i] & np.isfinite(ex[i])
            fin = sel & np.isfinite(b[i])
            with np.errstate(invalid="ignore"):
                d = b[i] - ex[i]
            err = np.abs(d)[fin]
            cons = np.where(left[i], -d, d)[fin]
            tag = "straight" if np.isinf(rad) else f"r{int(rad)}"
            vals = {
                "mean_err": float(err.mean()) if err.size else float("nan"),
                "p95_err": float(np.percentile(err, 95)) if err.size else float("nan"),
                "unsafe_share": float(np.asarray(r["unsafe"])[i][sel].mean()) if sel.any() else float("nan"),
                "conservative_share": float((cons > 0.2).sum() / max(sel.sum(), 1)),
                "missing_share": float(1 - fin.sum() / max(sel.sum(), 1)),
                "collide_share": float(np.asarray(r["collide"])[i][np.asarray(r["qp_ok"])[i]].mean())
                if np.asarray(r["qp_ok"])[i].any()
                else float("nan"),
                "unsafe_5cm_share": float(
                    (cons < -0.05).sum() / max(sel.sum(), 1) + (sel & ~np.isfinite(b[i])).sum() / max(sel.sum(), 1)
                ),
                "qp_infeasible_share": float(1 - np.asarray(r["qp_feasible"])[i].mean()),
                "qp_fail_share": float(1 - np.asarray(r["qp_ok"])[i].mean()),
                "pairs": int(sel.sum()),
            }
            for k, v in vals.items():
                m[f"{meth}.{tag}.{k}"] = round(v, 4) if isinstance(v, float) else v
            rows.append(vals)
        per[meth] = rows
    small = [i for i, r in enumerate(radii) if r <= 12]
    for meth in METHODS:
        err = []
        b = np.asarray(res[meth]["bound"])
        for i in small:
            sel = ov[i] & np.isfinite(ex[i]) & np.isfinite(b[i])
            err.append(np.abs(np.where(sel, b[i], 0.0) - np.where(sel, ex[i], 0.0))[sel])
        m[f"{meth}.r_le12.mean_err"] = round(float(np.concatenate(err).mean()), 4)
    m["claim.r_le12.centerline_over_contour"] = round(
        m["centerline.r_le12.mean_err"] / max(m["contour.r_le12.mean_err"], 1e-9), 3
    )
    m["claim.r_le12.contour_3x_better"] = float(m["claim.r_le12.centerline_over_contour"] >= 3.0)
    case = np.asarray(res["contour"]["case"])[ov & np.isfinite(ex)]
    for c, name in enumerate(
        ["none", "on_edge", "off_edge", "deepest", "no_corner", "degenerate", "exact", "unconstructed"]
    ):
        m[f"contour.case_share.{name}"] = round(float(np.mean(case == c)), 4)
    m["claim.r_le12.slbox_over_contour"] = round(
        m["slbox.r_le12.mean_err"] / max(m["contour.r_le12.mean_err"], 1e-9), 3
    )
    p = {k: np.asarray(v) for k, v in res["path"].items()}
    for i, rad in enumerate(radii):
        tag = "straight" if np.isinf(rad) else f"r{int(rad)}"
        m[f"path.{tag}.ok_share"] = round(float(p["ok"][i].mean()), 4)
    feas = p["corridor_ok"] & ~p["qp_infeasible"]
    solved = p["qp_ok"] & p["corridor_ok"]
    m["path.frames"] = int(p["ok"].size)
    m["path.ok_share"] = round(float(p["ok"].mean()), 4)
    m["path.blocked_share"] = round(float(p["blocked"].mean()), 4)
    m["path.corridor_feasible_share"] = round(float(p["corridor_ok"].mean()), 4)
    m["path.qp_infeasible_share"] = round(float((p["corridor_ok"] & p["qp_infeasible"]).mean()), 4)
    m["path.qp_success_on_feasible"] = round(float(p["qp_ok"][feas].mean()) if feas.any() else float("nan"), 4)
    m["path.collide_share_of_solved"] = round(float((~p["clear"][solved]).mean()) if solved.any() else float("nan"), 4)
    verdict = _osqp_verdicts(p, p["corridor_ok"])
    if verdict is not None:
        sol = verdict == "solved"
        m["path.osqp_solved_share"] = round(float(sol.mean()), 4)
        m["path.osqp_infeasible_share"] = round(float((verdict == "infeasible").mean()), 4)
        m["path.qp_success_on_osqp_solved"] = round(float(p["qp_ok"][sol].mean()) if sol.any() else float("nan"), 4)
        m["path.osqp_undecided_share"] = round(float((verdict == "undecided").mean()), 4)
        m["path.qp_ok_where_osqp_infeasible"] = int((p["qp_ok"] & (verdict == "infeasible")).sum())
        m["path.qp_ok_where_osqp_undecided"] = int((p["qp_ok"] & (verdict == "undecided")).sum())
    m["path.mean_rounds"] = round(float(p["rounds"].mean()), 3)
    return m, per


@register("bounds")
def bounds_suite(args: SuiteArgs) -> dict:
    n_frames = args.n or (12 if args.quick else 200)
    n_obs = 4 if args.quick else 8
    rng = np.random.default_rng(args.seed)
    refs, S, L, OBS, _, BOX = make_scenarios(rng, n_frames, n_obs)
    res = jax.tree_util.tree_map(
        np.asarray, _all_radii(jnp.asarray(refs), jnp.asarray(S), jnp.asarray(L), jnp.asarray(OBS), jnp.asarray(BOX))
    )
    m, per = _figures(res, RADII)
    m["frames_per_radius"] = n_frames
    m["obstacles_per_frame"] = n_obs
    _plot_error(per, args.out)
    _plot_frame(refs, S, L, OBS, res, args.out)
    return m


def _plot_error(per, out):
    import matplotlib.pyplot as plt

    x = np.arange(len(RADII))
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for meth in METHODS:
        if meth == "exact":
            continue
        ax[0].plot(x, [r["mean_err"] for r in per[meth]], "o-", label=meth)
        ax[1].plot(x, [r["p95_err"] for r in per[meth]], "o-", label=meth)
    for a, t in zip(ax, ["mean |bound - exact|", "95th percentile |bound - exact|"]):
        a.set_xticks(x, ["straight" if np.isinf(r) else f"{int(r)}" for r in RADII])
        a.set_xlabel("road radius [m]")
        a.set_ylabel("[m]")
        a.set_title(t)
        a.set_yscale("symlog", linthresh=1e-3)
        a.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(out, "bounds_error_vs_radius.png"), dpi=90)
    plt.close(fig)


def _plot_frame(refs, S, L, OBS, res, out, radius_index=1):
    import matplotlib.pyplot as plt

    i = radius_index
    ov = res["exact"]["overlap"][i]
    score = ov.sum(axis=(1, 2)) + 1000 * res["contour"]["qp_ok"][i]
    f = int(np.argmax(score))  # the frame with the most overlaps, preferring a planned one
    ref = reference_line(jnp.asarray(refs[i]))
    s = jnp.asarray(S[i, f])
    _, th, _, _ = ref_state(ref, s)
    n = np.stack([-np.sin(np.asarray(th)), np.cos(np.asarray(th))], -1)
    base = np.asarray(to_cartesian(ref, s, jnp.zeros_like(s)))
    fig, ax = plt.subplots(figsize=(8, 7))
    ax.plot(refs[i][:, 0], refs[i][:, 1], "k:", lw=1, label="reference line")
    for k in range(OBS.shape[2]):
        for tt in range(0, T, 6):
            q = OBS[i, f, k, tt]
            ax.fill(q[:, 0], q[:, 1], color="C3", alpha=0.15 + 0.1 * (tt == 0))
    dec = np.asarray(to_cartesian(ref, s, jnp.asarray(L[i, f])))
    ax.plot(dec[:, 0], dec[:, 1], "k.-", lw=1, label="decision trajectory")
    cars = np.asarray(vehicle_corners(jnp.asarray(dec), CAR))
    for tt in range(0, T, 3):
        c = np.vstack([cars[tt], cars[tt][:1]])
        ax.plot(c[:, 0], c[:, 1], color="0.5", lw=0.7)
    for meth, col in (("centerline", "C0"), ("slbox", "C1"), ("contour", "C2")):
        r = res[meth]
        for key, ls in (("upper", "--"), ("lower", "-.")):
            b = np.clip(r[key][i, f], -LANE, LANE)
            p = base + b[:, None] * n
            ax.plot(p[:, 0], p[:, 1], ls, color=col, lw=1.2, label=f"{meth} {key}")
        if r["qp_ok"][i, f]:
            p = np.asarray(to_cartesian(ref, s, jnp.asarray(r["qp_l"][i, f])))
            ax.plot(p[:, 0], p[:, 1], "-", color=col, lw=2.2, alpha=0.6, label=f"optimised path ({meth})")
    pp = res["path"]
    if pp["qp_ok"][i, f]:
        xy = pp["xy"][i, f]
        ax.plot(xy[:, 0], xy[:, 1], "-", color="C4", lw=2.5, label="planner's path (decision, buffer, heading rounds)")
        cars = np.asarray(vehicle_corners(jnp.asarray(xy), CAR, jnp.asarray(pp["theta"][i, f])))
        for tt in range(0, len(xy), 6):
            c = np.vstack([cars[tt], cars[tt][:1]])
            ax.plot(c[:, 0], c[:, 1], color="C4", lw=0.8)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=7, loc="best")
    ax.set_title(f"radius {RADII[i]:g} m, frame {f}: bounds and optimised paths")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "bounds_frame.png"), dpi=90)
    plt.close(fig)
