"""Suite ``geometry``: oracle agreement with shapely and throughput of the core."""

from __future__ import annotations

import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.eval.registry import SuiteArgs, register
from jaxplan.geometry import has_overlap, overlap_polygon_tagged, polygon_area
from jaxplan.scenarios.shapes import random_convex_polygons


def _area(a, b, va, vb):
    out = overlap_polygon_tagged(a, b, va, vb)
    return polygon_area(out.vertices, out.valid)


_area_jit = jax.jit(_area)
_overlap_jit = jax.jit(has_overlap)


def _rate(fn, *xs, reps=3):
    jax.block_until_ready(fn(*xs))
    t0 = time.perf_counter()
    for _ in range(reps):
        jax.block_until_ready(fn(*xs))
    return reps * xs[0].shape[0] / (time.perf_counter() - t0)


@register("geometry")
def geometry_suite(args: SuiteArgs) -> dict:
    n = args.n or (2000 if args.quick else 20000)
    rng = np.random.default_rng(args.seed)
    a, va = random_convex_polygons(rng, n)
    b, vb = random_convex_polygons(rng, n)
    aj, bj = jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32)
    ours_area = np.asarray(_area_jit(aj, bj, va, vb))
    ours_hit = np.asarray(_overlap_jit(aj, bj, va, vb))
    m = {
        "pairs": n,
        "overlap_pairs_per_s": round(_rate(_overlap_jit, aj, bj, va, vb)),
        "area_pairs_per_s": round(_rate(_area_jit, aj, bj, va, vb)),
    }
    try:
        import shapely
    except ImportError:  # oracle figures need the test extra
        return m
    A = np.empty(n, object)
    A[:] = [shapely.Polygon(p[k]) for p, k in zip(a, va)]
    B = np.empty(n, object)
    B[:] = [shapely.Polygon(p[k]) for p, k in zip(b, vb)]
    ref = shapely.area(shapely.intersection(A, B))
    truth = shapely.relate_pattern(A, B, "T********")
    big = ref > 1e-3
    rel = np.abs(ours_area - ref)[big] / ref[big]
    m.update(
        {
            "overlap_agreement": float(np.mean(ours_hit == truth)),
            "area_rel_err_max_f32": float(rel.max()) if big.any() else 0.0,
            "area_rel_err_mean_f32": float(rel.mean()) if big.any() else 0.0,
        }
    )
    _plot(a, va, b, vb, ref, ours_area, args.out)
    return m


def _plot(a, va, b, vb, ref, ours, out):
    import matplotlib.pyplot as plt

    from jaxplan.geometry import overlap_polygon

    fig, ax = plt.subplots(1, 2, figsize=(10, 4.5))
    idx = np.nonzero(ref > 1.0)[0][:1]
    for i in idx:
        for p, k, c in ((a[i], va[i], "C0"), (b[i], vb[i], "C1")):
            q = p[k]
            ax[0].fill(q[:, 0], q[:, 1], alpha=0.3, color=c)
        v, ok = overlap_polygon(jnp.asarray(a[i]), jnp.asarray(b[i]), va[i], vb[i])
        q = np.asarray(v)[np.asarray(ok)]
        ax[0].fill(q[:, 0], q[:, 1], facecolor="none", edgecolor="k", lw=2, label="overlap polygon")
        ax[0].plot(q[:, 0], q[:, 1], "ko")
    ax[0].set_aspect("equal")
    ax[0].legend()
    ax[0].set_title("two random convex polygons and their overlap")
    ax[1].loglog(np.maximum(ref, 1e-6), np.maximum(np.abs(ours - ref), 1e-12), ".", ms=2)
    ax[1].set_xlabel("shapely intersection area [m^2]")
    ax[1].set_ylabel("|jaxplan - shapely| [m^2] (float32)")
    ax[1].set_title("overlap area error")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "geometry.png"), dpi=90)
    plt.close(fig)
