"""Recorded vehicles across scenario files, and splits that keep each vehicle on one side.

NGSIM scenario files are overlapping cut-outs of one recording: ``USA_US101-15`` and
``USA_US101-5`` hold the same vehicles 5.3 s apart with shifted coordinates, and ids
are not reliable either way (the same vehicle can carry different ids in two files).
Two tracks are taken to be one vehicle (``vehicle_links``) when

- **shape and timing** agree: the same size (1 cm) and, for some time shift, the same
  step vectors (1 mm) over at least ``min_overlap`` seconds in which it moved at least
  ``min_travel`` metres (a translated copy of the recording), or
- **id and size** agree within one location (conservative: two different vehicles
  with the same id and the same size to 1 mm would only be kept on the same side).

The identities are the connected components of these links (union-find), so a
split by identity (``split_by_vehicle``) never trains and validates on the same car.
"""

from __future__ import annotations

import zlib
from collections import defaultdict

import numpy as np

from jaxplan.tuning.demos import DemoIndex, location_of


def _tracks(sc):
    """``[(obstacle id, first step, xy (n, 2), (length, width))]`` of the moving recorded vehicles
    (their longest run of valid steps)."""
    boxes = np.asarray(sc.obstacles.boxes, np.float64)
    valid = np.asarray(sc.obstacles.valid)
    static = np.asarray(sc.obstacles.static, bool)
    out = []
    for i in range(boxes.shape[0]):
        if static[i] or not valid[i].any():
            continue
        v = np.concatenate([[False], valid[i], [False]])
        starts, ends = np.nonzero(~v[:-1] & v[1:])[0], np.nonzero(v[:-1] & ~v[1:])[0]
        j = int(np.argmax(ends - starts))
        a, b = starts[j], ends[j]
        out.append((int(sc.obstacle_ids[i]), int(a), boxes[i, a:b, :2], (float(boxes[i, a, 2]), float(boxes[i, a, 3]))))
    return out


def _same_motion(xa, xb, min_steps: int, min_travel: float, tol: float) -> bool:
    """Whether the step vectors of ``xa (n, 2)`` and ``xb (m, 2)`` agree within ``tol`` for some
    time shift over at least ``min_steps`` steps covering ``min_travel`` metres."""
    ea, eb = np.diff(xa, axis=0), np.diff(xb, axis=0)
    for sh in range(-(len(eb) - min_steps), len(ea) - min_steps + 1):
        i0 = max(0, sh)
        j0 = i0 - sh
        n = min(len(ea) - i0, len(eb) - j0)
        if n < min_steps:
            continue
        seg = ea[i0 : i0 + n]
        if np.abs(seg - eb[j0 : j0 + n]).max() < tol and np.linalg.norm(seg, axis=1).sum() >= min_travel:
            return True
    return False


def vehicle_links(
    scenarios, min_overlap: float = 1.0, min_travel: float = 3.0, size_tol: float = 0.01, step_tol: float = 1e-3
) -> list[tuple]:
    """Pairs of tracks in different scenarios taken to be one vehicle (see the module docstring).

    Returns:
        ``[((scenario a, obstacle a), (scenario b, obstacle b), reason)]`` with reason
        ``"motion"`` or ``"id+size"``.
    """
    scenarios = list(scenarios)
    tracks = {sc.id: _tracks(sc) for sc in scenarios}
    dts = {sc.id: sc.dt for sc in scenarios}
    by_loc = defaultdict(list)
    for sid in tracks:
        by_loc[location_of(sid)].append(sid)
    links = []
    for sids in by_loc.values():
        # bucket by size (1 cm grid, neighbours included) so only same-size tracks are compared
        buckets = defaultdict(list)
        for sid in sids:
            for oid, _k0, xy, (ln, wd) in tracks[sid]:
                buckets[(round(ln / size_tol), round(wd / size_tol))].append((sid, oid, xy, ln, wd))
        seen = set()
        for (bl, bw), items in buckets.items():
            near = [it for dl in (-1, 0, 1) for dw in (-1, 0, 1) for it in buckets.get((bl + dl, bw + dw), [])]
            for a in items:
                for b in near:
                    if a[0] == b[0] or abs(a[3] - b[3]) > size_tol or abs(a[4] - b[4]) > size_tol:
                        continue
                    key = tuple(sorted([(a[0], a[1]), (b[0], b[1])]))
                    if key in seen:
                        continue
                    seen.add(key)
                    if a[1] == b[1] and abs(a[3] - b[3]) < 1e-3 and abs(a[4] - b[4]) < 1e-3:
                        links.append((key[0], key[1], "id+size"))
                        continue
                    steps = max(2, int(round(min_overlap / dts[a[0]])))
                    if abs(dts[a[0]] - dts[b[0]]) < 1e-9 and _same_motion(a[2], b[2], steps, min_travel, step_tol):
                        links.append((key[0], key[1], "motion"))
    return links


def vehicle_identities(scenarios, **kw) -> dict:
    """``{(scenario id, obstacle id): identity}``: one name per recorded vehicle across
    scenarios (the connected components of ``vehicle_links``), the smallest
    ``"scenario:obstacle"`` of its component."""
    scenarios = list(scenarios)
    parent: dict[tuple[str, int], tuple[str, int]] = {}

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for sc in scenarios:
        for oid in np.asarray(sc.obstacle_ids):
            parent[(sc.id, int(oid))] = (sc.id, int(oid))
    for a, b, _ in vehicle_links(scenarios, **kw):
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    name = lambda x: f"{x[0]}:{x[1]}"
    smallest: dict[tuple[str, int], str] = {}
    for x in parent:
        r = find(x)
        smallest[r] = min(smallest.get(r, name(x)), name(x))
    return {x: smallest[find(x)] for x in parent}


def vehicle_names(index: DemoIndex) -> np.ndarray:
    """``(B,)`` each demonstration's vehicle identity (its own ``scenario:obstacle`` where unknown)."""
    return np.array(
        [v if v else f"{s}:{o}" for v, s, o in zip(index.vehicle, index.scenario, index.obstacle_id)], dtype=object
    )


def split_by_vehicle(index: DemoIndex, share: int = 4, salt: str = "") -> np.ndarray:
    """``(B,)`` bool, True for validation: one vehicle identity in ``share``, by a hash of
    its name (the same vehicle goes the same way whichever files are loaded together)."""
    return np.array([zlib.crc32((salt + n).encode()) % share == 0 for n in vehicle_names(index)], bool)


def disjoint(index_a: DemoIndex, index_b: DemoIndex) -> bool:
    """Whether no vehicle identity has demonstrations in both sets."""
    return not set(vehicle_names(index_a).tolist()) & set(vehicle_names(index_b).tolist())
