"""Suite ``parkout``: gap sweep of the parallel park-out planner against the two-corner baseline."""
from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.eval.registry import SuiteArgs, register
from jaxplan.geometry import box_corners, box_has_overlap, segment_point_distance
from jaxplan.parking import (ParkoutConfig, footprint_boxes, make_scenes, min_front_gap, min_slot_length,
                             park_out, render_grid, stop_line)
from jaxplan.types import VehicleParams


def _corner_edge_dist(ca, cb):
    """Smallest distance from corners ``(..., 4, 2)`` of A to the edges of B ``(..., 4, 2)``."""
    a = ca[..., :, None, :]
    return jnp.min(segment_point_distance(a, cb[..., None, :, :], jnp.roll(cb, -1, -2)[..., None, :, :]), (-2, -1))


@jax.jit
def run_metrics(poses, valid, boxes, box_valid, vehicle):
    """Per run: any executed footprint overlapping a true obstacle, and the smallest clearance.

    Args:
        poses: ``(B, M, T, 3)``; valid: ``(B, M, T)``; boxes: ``(B, K, 5)``.

    Returns:
        (collided ``(B,)``, clearance ``(B,)`` in metres, 0 where overlapping).
    """
    fb = footprint_boxes(poses, vehicle)[..., None, :]  # (B, M, T, 1, 5)
    ob = boxes[:, None, None]  # (B, 1, 1, K, 5)
    hit = box_has_overlap(fb, ob) & box_valid[:, None, None] & valid[..., None]
    ca, cb = box_corners(fb), box_corners(ob)
    d = jnp.minimum(_corner_edge_dist(ca, cb), _corner_edge_dist(cb, ca))
    d = jnp.where(box_has_overlap(fb, ob), 0.0, d)
    d = jnp.where(box_valid[:, None, None] & valid[..., None], d, jnp.inf)
    return jnp.any(hit, (1, 2, 3)), jnp.min(d, (1, 2, 3))


def sweep(n_per_gap: int, gaps, seed: int, config: ParkoutConfig, vehicle: VehicleParams, noise: bool = True):
    """Scenes with equal front and rear gap ``g`` for each ``g`` in ``gaps``; both models, one batched call each."""
    rng = np.random.default_rng(seed)
    g = np.repeat(np.asarray(gaps, float), n_per_gap)
    kw = dict(heading_noise_deg=1.5, offset_noise=0.1, edge_noise=0.03, salt=1e-5) if noise else {}
    scene, info = make_scenes(rng, len(g), vehicle, front_gap=g, rear_gap=g, **kw)
    key = jnp.asarray([seed, 17], jnp.uint32)
    out = {}
    for model in ("grid", "two_corner"):
        res = jax.block_until_ready(park_out(scene, key, config, vehicle, model))
        coll, clear = map(np.asarray, run_metrics(res.poses, res.valid, scene.boxes, scene.valid, vehicle))
        out[model] = dict(res=res, collided=coll, clearance=clear, success=np.asarray(res.success) & ~coll)
    need = np.asarray(min_front_gap(vehicle, config.margin, info["front_corner_y"]))
    info["slot_min"] = float(vehicle.length) + config.margin + need
    info["gap"] = g
    return scene, info, out


@register("parkout")
def parkout_suite(args: SuiteArgs) -> dict:
    car = VehicleParams()
    cfg = ParkoutConfig()
    gaps = np.round(np.linspace(0.3, 2.4, 8), 3)
    n = args.n or (8 if args.quick else 64)
    scene, info, out = sweep(n, gaps, args.seed, cfg, car)
    G, Tc = out["grid"], out["two_corner"]
    m = {"scenes": int(len(info["gap"])), "slot_min_analytic_m": round(float(min_slot_length(car, cfg.margin)), 3),
         "slot_min_analytic_no_margin_m": round(float(min_slot_length(car)), 3)}
    moves = np.asarray(G["res"].moves)
    length = np.asarray(G["res"].path_length)
    for gval in gaps:
        sel = info["gap"] == gval
        ok = G["success"][sel]
        tag = f"gap_{gval:.2f}"
        m[f"{tag}.slot_length_m"] = round(float(car.length + 2 * gval), 3)
        m[f"{tag}.success_rate"] = float(ok.mean())
        m[f"{tag}.moves_mean"] = float(moves[sel][ok].mean()) if ok.any() else float("nan")
        m[f"{tag}.path_length_mean_m"] = float(length[sel][ok].mean()) if ok.any() else float("nan")
        m[f"{tag}.clearance_min_m"] = float(G["clearance"][sel].min())
        m[f"{tag}.two_corner_success_rate"] = float(Tc["success"][sel].mean())
        m[f"{tag}.two_corner_collision_rate"] = float(Tc["collided"][sel].mean())
    slot = info["slot_length"]
    above = slot >= info["slot_min"]
    m["claim.grid_runs_with_collision"] = int(G["collided"].sum())
    failed = ~np.asarray(G["res"].success)
    m["claim.grid_failed_stuck"] = int((failed & np.asarray(G["res"].stuck)).sum())
    m["claim.grid_failed_out_of_moves"] = int((failed & ~np.asarray(G["res"].stuck)).sum())
    m["claim.scenes_slot_ge_min"] = int(above.sum())
    m["claim.success_rate_slot_ge_min"] = float(G["success"][above].mean()) if above.any() else float("nan")
    band = slot >= info["slot_min"] + 0.3
    m["claim.success_rate_slot_ge_min_plus_0.3"] = float(G["success"][band].mean()) if band.any() else float("nan")
    m["claim.success_rate_slot_lt_min"] = float(G["success"][~above].mean()) if (~above).any() else float("nan")
    m["claim.two_corner_runs_with_collision"] = int(Tc["collided"].sum())
    m["claim.two_corner_failed_or_collided_where_grid_succeeds"] = int((G["success"] & ~Tc["success"]).sum())
    m["claim.grid_success_total"] = int(G["success"].sum())
    # the same sweep without start / grid noise (same shapes: no new compile)
    _, info0, out0 = sweep(n, gaps, args.seed, cfg, car, noise=False)
    above0 = info0["slot_length"] >= info0["slot_min"]
    m["claim.noise_free.grid_runs_with_collision"] = int(out0["grid"]["collided"].sum())
    m["claim.noise_free.success_rate_slot_ge_min"] = float(out0["grid"]["success"][above0].mean())
    m["claim.noise_free.two_corner_runs_with_collision"] = int(out0["two_corner"]["collided"].sum())
    _plot(args.out, scene, info, out, gaps, cfg, car)
    return m


def _plot(out_dir, scene, info, out, gaps, cfg, car):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    G, Tc = out["grid"], out["two_corner"]
    moves = np.asarray(G["res"].moves)
    fig, ax = plt.subplots(figsize=(6.5, 4))
    slot = car.length + 2 * np.asarray(gaps)
    for res, lab in ((G, "occupancy grid"), (Tc, "two corners per obstacle")):
        ax.plot(slot, [res["success"][info["gap"] == g].mean() for g in gaps], "o-", label=lab)
    ax.plot(slot, [Tc["collided"][info["gap"] == g].mean() for g in gaps], "x--", label="two corners: collision rate")
    ax.axvline(float(min_slot_length(car, cfg.margin)), color="k", ls=":", label="analytic min (one forward move)")
    ax.set_xlabel("slot length, bumper to bumper [m]")
    ax.set_ylabel("rate")
    ax.set_ylim(-0.05, 1.05)
    ax.legend(fontsize=8)
    ax.set_title("park-out success vs slot length")
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, "parkout_success.png"), dpi=90)
    plt.close(fig)

    # maneuver sequence over the grid of one multi-move success (else any success)
    cand = np.nonzero(G["success"] & (moves > 1))[0]
    if not len(cand):
        cand = np.nonzero(G["success"])[0]
    i = int(cand[0]) if len(cand) else 0
    one = jax.tree_util.tree_map(lambda x: x[i], scene)
    grid = render_grid(one, jnp.zeros(3), jnp.asarray([0, 1], jnp.uint32), cfg, car)
    h = cfg.cell
    fig, ax = plt.subplots(figsize=(9, 5))
    ax.imshow(np.asarray(grid.cells), origin="lower", cmap="Greys", alpha=0.6,
              extent=(-cfg.cols * h / 2, cfg.cols * h / 2, -cfg.rows * h / 2, cfg.rows * h / 2))
    p, v, gear = (np.asarray(x[i]) for x in (G["res"].poses, G["res"].valid, G["res"].gear))
    for k in range(int(moves[i])):
        q = p[k][v[k]]
        col = "C0" if gear[k] > 0 else "C3"
        ax.plot(q[:, 0], q[:, 1], color=col, lw=2, label=("forward" if gear[k] > 0 else "backward") if k < 2 else None)
        c = np.asarray(box_corners(footprint_boxes(jnp.asarray(q[-1]), car)))
        ax.fill(c[:, 0], c[:, 1], facecolor="none", edgecolor=col, lw=1)
    c = np.asarray(box_corners(footprint_boxes(jnp.zeros(3), car)))
    ax.fill(c[:, 0], c[:, 1], facecolor="none", edgecolor="k", lw=1.5, label="start")
    ax.axhline(float(stop_line(car, cfg.c)), color="g", ls="--", label="stop line y = d")
    ax.set_xlim(-7, 10)
    ax.set_ylim(-3, 5)
    ax.set_aspect("equal")
    ax.legend(fontsize=8, loc="upper left")
    ax.set_title(f"park-out maneuvers, gap {info['gap'][i]:.2f} m, {int(moves[i])} moves (grid read at the start)")
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, "parkout_maneuvers.png"), dpi=90)
    plt.close(fig)
