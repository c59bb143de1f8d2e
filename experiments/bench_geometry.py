"""Benchmark: jaxplan's geometry core against shapely 2.x and pycrcc on random box pairs.

Prints pairs/s for each and the ratios, and writes JSON (``--out``). Compile
time is reported separately. Peers that are not installed are skipped
(``pip install -e .[bench]``).

    python experiments/bench_geometry.py [--n 100000] [--out results/bench_geometry.json]
"""
from __future__ import annotations

import argparse
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry import (box_corners, box_has_overlap, has_overlap, overlap_area,
                              overlap_polygon_tagged, polygon_area)
from jaxplan.scenarios.shapes import random_boxes
from jaxplan.eval.timing import best_time, write_figures



def _jax_rate(f, args, n, reps):
    t = time.perf_counter()
    jax.block_until_ready(f(*args))
    compile_s = time.perf_counter() - t
    return n / best_time(lambda: jax.block_until_ready(f(*args)), reps), compile_s


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--out", default="results/bench_geometry.json")
    args = ap.parse_args(argv)
    n = args.n
    rng = np.random.default_rng(0)
    ba, bb = random_boxes(rng, n), random_boxes(rng, n)
    ja, jb = jnp.asarray(ba, jnp.float32), jnp.asarray(bb, jnp.float32)
    ca, cb = jax.jit(box_corners)(ja), jax.jit(box_corners)(jb)

    def poly_area(a, b):
        o = overlap_polygon_tagged(a, b)
        return polygon_area(o.vertices, o.valid)

    res = {"n_pairs": n, "device": str(jax.devices()[0]), "cpu_count": os.cpu_count(),
           "machine": platform.machine()}
    for name, f, xs in [("jaxplan_box_overlap", box_has_overlap, (ja, jb)),
                        ("jaxplan_polygon_overlap", has_overlap, (ca, cb)),
                        ("jaxplan_overlap_area", overlap_area, (ca, cb)),
                        ("jaxplan_overlap_polygon_area", poly_area, (ca, cb))]:
        rate, comp = _jax_rate(jax.jit(f), xs, n, args.reps)
        res[f"{name}_pairs_per_s"] = rate
        res[f"{name}_compile_s"] = comp
    try:
        import shapely

        A = shapely.polygons(np.asarray(ca, np.float64))
        B = shapely.polygons(np.asarray(cb, np.float64))
        res["shapely_intersects_pairs_per_s"] = n / best_time(lambda: shapely.intersects(A, B), args.reps)
        res["shapely_intersection_area_pairs_per_s"] = n / best_time(
            lambda: shapely.area(shapely.intersection(A, B)), max(1, args.reps // 2))
    except ImportError:
        print("shapely not installed: skipped")
    try:
        import commonroad_dc.pycrcc as pycrcc

        m = int(np.sqrt(n))  # all pairs of two groups of m boxes: m * m checks

        def group(b):
            g = pycrcc.ShapeGroup()
            for x, y, length, width, h in b:
                g.add_shape(pycrcc.RectOBB(length / 2, width / 2, h, x, y))
            return g

        ga, gb = group(ba[:m]), group(bb[:m])
        res["pycrcc_box_pairs_per_s"] = m * m / best_time(lambda: ga.overlap(gb), args.reps)
        jall = jax.jit(lambda a, b: box_has_overlap(a[:, None], b[None, :]))
        rate, _ = _jax_rate(jall, (ja[:m], jb[:m]), m * m, args.reps)
        res["jaxplan_box_overlap_all_pairs_per_s"] = rate
        # Same verdicts on the same all-pairs problem.
        ours = np.asarray(jall(ja[:m], jb[:m]))
        theirs = np.zeros((m, m), bool)
        for i, j in ga.overlap(gb):
            theirs[i, j] = True
        res["pycrcc_agreement"] = float(np.mean(ours == theirs))
    except ImportError:
        print("commonroad-drivability-checker not installed: skipped")

    r = res
    if "shapely_intersection_area_pairs_per_s" in r:
        r["ratio_polygon_area_vs_shapely"] = r["jaxplan_overlap_polygon_area_pairs_per_s"] / r[
            "shapely_intersection_area_pairs_per_s"]
        r["ratio_area_vs_shapely"] = r["jaxplan_overlap_area_pairs_per_s"] / r["shapely_intersection_area_pairs_per_s"]
        r["ratio_overlap_vs_shapely_intersects"] = r["jaxplan_box_overlap_pairs_per_s"] / r[
            "shapely_intersects_pairs_per_s"]
    if "pycrcc_box_pairs_per_s" in r:
        r["ratio_box_overlap_vs_pycrcc"] = r["jaxplan_box_overlap_all_pairs_per_s"] / r["pycrcc_box_pairs_per_s"]
    write_figures(r, args.out, 45)
    return r


if __name__ == "__main__":
    main()
