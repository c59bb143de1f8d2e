"""Suite ``parkout``: gap sweep against the two-corner baseline, both road sides, and the scene families.

Every executed footprint is judged against the true obstacle outlines with the
geometry core's polygon SAT (``run_metrics``), independent of the planner's grid.
"""

from __future__ import annotations

import os
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.eval.registry import SuiteArgs, register
from jaxplan.geometry import box_corners, has_overlap, segment_point_distance
from jaxplan.parking import (
    ParkoutConfig,
    footprint_boxes,
    make_scenes,
    min_front_gap,
    min_slot_length,
    park_out,
    render_scenes,
    stop_line,
)
from jaxplan.parking.families import FAMILIES, family_scenes, scene_dicts
from jaxplan.parking.profile import speed_profile_jit
from jaxplan.parking.scene_file import problem_from_dict, stack_parking_scenes
from jaxplan.parking.scenes import ParkingScene
from jaxplan.types import VehicleParams


def _vertex_edge_dist(ca, cb):
    """Smallest distance from vertices ``(..., N, 2)`` of A to the edges of B ``(..., M, 2)``."""
    a = ca[..., :, None, :]
    return jnp.min(segment_point_distance(a, cb[..., None, :, :], jnp.roll(cb, -1, -2)[..., None, :, :]), (-2, -1))


@jax.jit
def _pose_metrics(poses, polygons, poly_valid, vehicle):
    """Overlap and clearance of footprints at poses ``(C, 3)`` with their scenes' outlines ``(C, K, N, 2)``."""
    ca = box_corners(footprint_boxes(poses, vehicle))[:, None]  # (C, 1, 4, 2)
    over = has_overlap(ca, polygons) & poly_valid
    d = jnp.minimum(_vertex_edge_dist(ca, polygons), _vertex_edge_dist(polygons, ca))
    d = jnp.where(poly_valid, jnp.where(over, 0.0, d), jnp.inf)
    return jnp.any(over, -1), jnp.min(d, -1)


CHUNK = 8192


def run_metrics(poses, valid, polygons, poly_valid, vehicle):
    """Per run: any executed footprint overlapping a true obstacle, and the smallest clearance.

    Args:
        poses: ``(B, M, T, 3)``; valid: ``(B, M, T)``; polygons: ``(B, K, N, 2)``
            convex obstacle outlines (either orientation); poly_valid: ``(B, K)``.

    Returns:
        (collided ``(B,)``, clearance ``(B,)`` in metres, 0 where overlapping), numpy.
    """
    poses, valid = np.asarray(poses), np.asarray(valid)
    polygons, poly_valid = np.asarray(polygons), np.asarray(poly_valid)
    b, mm, t = np.nonzero(valid)
    q = poses[b, mm, t]
    B = valid.shape[0]
    coll = np.zeros(B, bool)
    clear = np.full(B, np.inf)
    for lo in range(0, len(b), CHUNK):
        idx = np.arange(lo, lo + CHUNK).clip(max=len(b) - 1)
        hit, d = _pose_metrics(
            jnp.asarray(q[idx]), jnp.asarray(polygons[b[idx]]), jnp.asarray(poly_valid[b[idx]]), vehicle
        )
        np.logical_or.at(coll, b[idx], np.asarray(hit))
        np.minimum.at(clear, b[idx], np.asarray(d))
    return coll, clear


def _judge(res, scene: ParkingScene, vehicle):
    return run_metrics(res.poses, res.valid, scene.polygons, scene.valid, vehicle)


def sweep(n_per_gap: int, gaps, seed: int, config: ParkoutConfig, vehicle: VehicleParams, noise: bool = True):
    """Scenes with equal front and rear gap ``g`` for each ``g`` in ``gaps``; both models, one batched call each."""
    rng = np.random.default_rng(seed)
    g = np.repeat(np.asarray(gaps, float), n_per_gap)
    kw: dict[str, Any] = dict(heading_noise_deg=1.5, offset_noise=0.1, edge_noise=0.03, salt=1e-5) if noise else {}
    scene, info = make_scenes(rng, len(g), vehicle, front_gap=g, rear_gap=g, **kw)
    out = {}
    for model in ("grid", "two_corner"):
        tm: dict[str, float] = {}
        res = park_out(scene, seed * 7919 + 17, config, vehicle, model, timing=tm)
        coll, clear = _judge(res, scene, vehicle)
        out[model] = dict(res=res, collided=coll, clearance=clear, success=np.asarray(res.success) & ~coll, timing=tm)
    need = np.asarray(min_front_gap(vehicle, config.margin, info["front_corner_y"]))
    info["slot_min"] = float(vehicle.length) + config.margin + need
    info["gap"] = g
    return scene, info, out


def side_sweep(n_per_gap: int, gaps, seed: int, config: ParkoutConfig, vehicle: VehicleParams):
    """Noise-free slots with equal gaps, planned with the road on the left and (through the scene-file
    loader, mirrored) on the right; returns ``{side: success (len(gaps) * n,)}`` and the gaps."""
    rng = np.random.default_rng(seed + 101)
    g = np.repeat(np.asarray(gaps, float), n_per_gap)
    scene, info = make_scenes(rng, len(g), vehicle, front_gap=g, rear_gap=g)
    out = {}
    for side in ("left", "right"):
        info["side"] = np.full(len(g), side)
        probs = [problem_from_dict(d) for d in scene_dicts(scene, info, vehicle, np.random.default_rng(seed))]
        sc = stack_parking_scenes([p.scene for p in probs])
        res = park_out(sc, seed, config, vehicle)
        coll, _ = _judge(res, sc, vehicle)
        out[side] = dict(success=np.asarray(res.success) & ~coll, collided=coll, moves=np.asarray(res.moves))
    return g, out


def min_gap(gaps, success):
    """Smallest swept gap from which every scene at it and at every larger gap succeeded (nan if none)."""
    ok = np.array([np.all(success[gaps == g]) for g in np.unique(gaps)])
    u = np.unique(gaps)
    if not ok[-1]:
        return float("nan")
    bad = np.nonzero(~ok)[0]
    return float(u[bad[-1] + 1] if len(bad) else u[0])


@register("parkout")
def parkout_suite(args: SuiteArgs) -> dict:
    car = VehicleParams()
    cfg = ParkoutConfig()
    gaps = np.round(np.linspace(0.3, 2.4, 8), 3)
    n = args.n or (8 if args.quick else 64)
    scene, info, out = sweep(n, gaps, args.seed, cfg, car)
    G, Tc = out["grid"], out["two_corner"]
    m = {
        "scenes": int(len(info["gap"])),
        "slot_min_analytic_m": round(float(min_slot_length(car, cfg.margin)), 3),
        "slot_min_analytic_no_margin_m": round(float(min_slot_length(car)), 3),
    }
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
    spare15 = slot >= car.length + 1.5
    m["claim.success_rate_spare_ge_1.5"] = float(G["success"][spare15].mean()) if spare15.any() else float("nan")
    m["claim.two_corner_runs_with_collision"] = int(Tc["collided"].sum())
    m["claim.two_corner_failed_or_collided_where_grid_succeeds"] = int((G["success"] & ~Tc["success"]).sum())
    m["claim.grid_success_total"] = int(G["success"].sum())
    m["claim.grid_searched_share"] = float(np.asarray(G["res"].searched).mean())
    m["timing.plan_s"] = round(G["timing"]["plan_s"], 3)
    m["timing.render_s"] = round(G["timing"]["render_s"], 3)
    # the same sweep without start / grid noise (same shapes: no new compile)
    _, info0, out0 = sweep(n, gaps, args.seed, cfg, car, noise=False)
    above0 = info0["slot_length"] >= info0["slot_min"]
    m["claim.noise_free.grid_runs_with_collision"] = int(out0["grid"]["collided"].sum())
    m["claim.noise_free.success_rate_slot_ge_min"] = float(out0["grid"]["success"][above0].mean())
    m["claim.noise_free.two_corner_runs_with_collision"] = int(out0["two_corner"]["collided"].sum())
    # both sides: the analytic minimum (one forward move) and the multi-move minimum gap
    fine = np.round(np.arange(0.3, 1.25, 0.05), 3)
    g2, sides = side_sweep(max(2, n // 8), fine, args.seed, cfg, car)
    for side, r in sides.items():
        m[f"side.{side}.analytic_min_front_gap_m"] = round(float(min_front_gap(car, cfg.margin)), 3)
        m[f"side.{side}.multi_move_min_gap_m"] = min_gap(g2, r["success"])
        m[f"side.{side}.runs_with_collision"] = int(r["collided"].sum())
        m[f"side.{side}.moves_at_min_gap_mean"] = (
            float(np.mean(r["moves"][g2 == m[f"side.{side}.multi_move_min_gap_m"]]))
            if np.isfinite(m[f"side.{side}.multi_move_min_gap_m"])
            else float("nan")
        )
    m["side.left_right_same_outcome_share"] = float(np.mean(sides["left"]["success"] == sides["right"]["success"]))
    # scene families (spare length 1.5 to 3 m)
    examples = {}
    nf = max(8, n // 2)
    for i, fam in enumerate(FAMILIES):
        rng = np.random.default_rng([args.seed, 17, i])
        fs, finfo = family_scenes(fam, rng, nf, car)
        if fam in ("right", "wall", "stopped", "angled"):  # through the scene-file loader, mirrored where right
            probs = [problem_from_dict(d) for d in scene_dicts(fs, finfo, car, rng)]
            fs = stack_parking_scenes([p.scene for p in probs])
        t0 = time.perf_counter()
        res = park_out(fs, args.seed + i, cfg, car)
        dt = time.perf_counter() - t0
        coll, clear = _judge(res, fs, car)
        ok = np.asarray(res.success) & ~coll
        _, t = speed_profile_jit(res.steer, res.valid, res.gear, cfg)
        tout = np.asarray(t).reshape(len(ok), -1).max(-1)
        tag = f"family.{fam}"
        m[f"{tag}.scenes"] = int(len(ok))
        m[f"{tag}.success_rate"] = float(ok.mean())
        m[f"{tag}.runs_with_collision"] = int(coll.sum())
        m[f"{tag}.moves_mean"] = float(np.asarray(res.moves)[ok].mean()) if ok.any() else float("nan")
        m[f"{tag}.path_length_mean_m"] = float(np.asarray(res.path_length)[ok].mean()) if ok.any() else float("nan")
        m[f"{tag}.time_to_out_mean_s"] = float(tout[ok].mean()) if ok.any() else float("nan")
        m[f"{tag}.clearance_min_m"] = float(clear.min())
        m[f"{tag}.searched_share"] = float(np.asarray(res.searched).mean())
        m[f"{tag}.wall_s"] = round(dt, 3)
        pick = np.nonzero(ok & (np.asarray(res.moves) > 1))[0]
        j = int(pick[0]) if len(pick) else 0
        examples[fam] = (
            jax.tree_util.tree_map(lambda a: np.asarray(a)[j], fs),
            jax.tree_util.tree_map(lambda a: np.asarray(a)[j], res),
        )
    _plot(args.out, scene, info, out, gaps, cfg, car, examples, (g2, sides))
    return m


def _plot(out_dir, scene, info, out, gaps, cfg, car, examples, side_data):
    import matplotlib.pyplot as plt

    from jaxplan.parking.plot import plot_parkout

    G, Tc = out["grid"], out["two_corner"]
    fig, ax = plt.subplots(figsize=(6.5, 4))
    slot = car.length + 2 * np.asarray(gaps)
    for res, lab in ((G, "occupancy grid"), (Tc, "two corners per obstacle")):
        ax.plot(slot, [res["success"][info["gap"] == g].mean() for g in gaps], "o-", label=lab)
    ax.plot(slot, [Tc["collided"][info["gap"] == g].mean() for g in gaps], "x--", label="two corners: collision rate")
    g2, sides = side_data
    u = np.unique(g2)
    for side, mk in (("left", "s:"), ("right", "^:")):
        ax.plot(
            car.length + 2 * u,
            [sides[side]["success"][g2 == g].mean() for g in u],
            mk,
            ms=3,
            label=f"noise-free, road on the {side}",
        )
    ax.axvline(float(min_slot_length(car, cfg.margin)), color="k", ls=":", label="analytic min (one forward move)")
    ax.set_xlabel("slot length, bumper to bumper [m]")
    ax.set_ylabel("rate")
    ax.set_ylim(-0.05, 1.05)
    ax.legend(fontsize=7)
    ax.set_title("park-out success vs slot length")
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, "parkout_success.png"), dpi=90)
    plt.close(fig)

    # maneuver sequence over the grid of one multi-move success (else any success)
    moves = np.asarray(G["res"].moves)
    cand = np.nonzero(G["success"] & (moves > 1))[0]
    if not len(cand):
        cand = np.nonzero(G["success"])[0]
    i = int(cand[0]) if len(cand) else 0
    one = jax.tree_util.tree_map(lambda x: np.asarray(x)[i : i + 1], scene)
    cells = np.asarray(render_scenes(one, 0, cfg, car).cells[0])
    res = jax.tree_util.tree_map(lambda x: np.asarray(x)[i], G["res"])
    polys = [p for p, v in zip(np.asarray(one.polygons[0]), np.asarray(one.valid[0])) if v]
    fig, ax = plt.subplots(figsize=(10, 5))
    plot_parkout(
        ax,
        polys,
        res,
        car,
        cfg,
        cells=cells,
        stop_y=float(stop_line(car, cfg.c)),
        title=f"park-out, gap {info['gap'][i]:.2f} m, {int(moves[i])} moves (one grid read at the start; "
        f"noise drawn anew for the picture)",
    )
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, "parkout_maneuvers.png"), dpi=90)
    plt.close(fig)

    fig, axs = plt.subplots(2, 3, figsize=(17, 5.6))
    for ax, (fam, (sc, res)) in zip(axs.ravel(), examples.items()):
        polys = [p for p, v in zip(sc.polygons, sc.valid) if v]
        sc1 = jax.tree_util.tree_map(lambda a: np.asarray(a)[None], sc)
        cells = np.asarray(render_scenes(sc1, 0, cfg, car).cells[0])
        plot_parkout(
            ax,
            polys,
            res,
            car,
            cfg,
            cells=cells,
            stop_y=float(stop_line(car, cfg.c)),
            title=f"{fam}: {'out' if res.success else 'failed'}, {int(res.moves)} moves"
            f"{' (search)' if res.searched else ''}",
        )
        if ax is not axs[0, 2]:
            ax.get_legend().remove()
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, "parkout_families.png"), dpi=80)
    plt.close(fig)
