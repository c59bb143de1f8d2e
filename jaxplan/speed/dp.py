"""Dynamic programming over the ST graph: exact (min) and smooth (soft-min) forms.

**Formulation.** Knot times ``t_k = k dt`` (k <= n_t). A state at ``t_k`` is the car's
station and its speed *at the knot*: ``s = c0 + i ds``, ``v = j dv`` with
``dv = 2 ds / dt`` and ``c0 = v0 dt / 2``; between knots the acceleration is constant, so
consecutive stations fix the speed: ``s_{k+1} - s_k = (v_k + v_{k+1}) dt / 2``, i.e. a
transition ``(i, j) -> (i + j + j', j')`` moves ``j + j'`` stations with acceleration
``(j' - j) dv / dt``. The first segment starts exactly at the car's speed ``v0`` (the
station offset ``c0`` makes every later station a grid point) with the exact
acceleration ``(v_1 - v0) / dt`` within ``SpeedConfig.first_accel_range`` (the limits
widened by half a step: the grid speed nearest to what they reach), and its jerk is taken
from the car's acceleration ``a0``. So the profile the DP returns *is* a kinematically exact
piecewise-constant-acceleration profile: its accelerations (not differences of segment
averages) lie in ``[a_min, a_max]`` after the first segment and its speeds in ``[0, v_max]``. The executed trajectory is the
smoothing QP's (``smooth.py``), which runs after the DP.

**Reachable band.** At ``t_k`` only the stations and speeds reachable from ``(0, v0)``
with accelerations in the first segment's range are states. Station and speed have the same
parity (``i_1 = j_1`` and every step adds ``j + j'``), so the DP indexes a state by
``h = (i - j) / 2 = j_1 + ... + j_{k-1}`` and ``j``: every speed, and a run of ``h`` of
static width (``dp_band``, the widest over every ``v0``) from an offset fixed by the
least first-knot speed (``dp_offsets``). ``band_widths`` / ``band_offsets`` give the
rectangle of reachable stations and speeds (``DPCosts.ilo``, ``jlo``).

The costs are ``jaxplan.speed.costs``; the problem's data ``jaxplan.speed.problem``.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.frenet import ReferenceLine
from jaxplan.speed.costs import COLLISION_V, DPCosts, stage_costs, table_origin, table_size, unreach
from jaxplan.speed.problem import CostWeights, SpeedConfig, SpeedPlan, SpeedRoad
from jaxplan.speed.st_graph import make_scene
from jaxplan.types import Obstacles, VehicleParams, is_concrete


@functools.cache
def substep_tables(config: SpeedConfig):
    """Static ``(V, M, n_sub + 1)`` tables for the sub-steps ``q = 0..n_sub`` of a segment
    starting at speed j with acceleration offset m: station offset (rounded, in ds),
    whether it is slower than ``keep_clear_v``, and its speed (m/s)."""
    c = config
    offs = np.asarray(c.accel_offsets)
    j = np.arange(c.n_v)[:, None, None]
    m = offs[None, :, None]
    q = np.arange(0, c.n_sub + 1)[None, None, :] / c.n_sub
    r = np.round(2 * j * q + m * q * q).astype(np.int32)
    v = (j + m * q) * c.dv
    return r, (v < c.keep_clear_v).astype(np.int32), v


def _h_range(jlo1, jhi1, k: int, c: SpeedConfig, xp=np):
    """Least and most ``h = j_1 + ... + j_{k-1}`` at knot ``k`` (1-based) over the speed
    sequences from a first knot speed in ``[jlo1, jhi1]`` (steps ``accel_offsets``, speeds
    in ``[0, n_v)``; each sum of the pointwise extreme sequences)."""
    offs = c.accel_offsets
    lo = hi = 0
    for l in range(1, k):
        lo = lo + xp.maximum(0, jlo1 + offs[0] * (l - 1))
        hi = hi + xp.minimum(c.n_v - 1, jhi1 + offs[-1] * (l - 1))
    return lo, hi


@functools.cache
def dp_band(config: SpeedConfig) -> tuple:
    """The DP's static band: ``(H, D, cap)``. At knot ``k`` the states are ``(h, j)``, ``h`` in
    ``[hlo_k, hlo_k + H[k-1])`` (``dp_offsets``), every speed ``j < n_v``; ``D``: the most
    first-knot speeds above the least; ``cap[k-1]``: the largest offset (the band never
    reaches past the largest reachable ``h``)."""
    c = config
    a_lo, a_hi = c.first_accel_range
    D = int(math.floor((a_hi - a_lo + 2e-4) * c.dt / c.dv + 1e-9))
    jlo = np.arange(c.n_v)
    H, cap, lo_prev = [], [], None
    for k in range(1, c.n_t + 1):
        lo, hi = _h_range(jlo, np.minimum(c.n_v - 1, jlo + D), k, c)
        Hk = int(np.max(hi - lo)) + 1
        H.append(Hk)
        cap.append(int(_h_range(0, c.n_v - 1, k, c)[1]) - Hk + 1)
        off = np.minimum(lo, cap[-1])
        # the step's table block (stations up to 2 (cap + H) + n_v) lies inside the table
        assert table_origin(c) + 2 * (cap[-1] + Hk) + c.n_v <= table_size(c), (k, cap[-1], Hk)
        if lo_prev is not None:  # the offsets grow by at most n_v - 1 a knot (the windows below)
            assert np.all(off >= lo_prev) and np.all(off - lo_prev < c.n_v), (k, off, lo_prev)
        lo_prev = off
    return tuple(H), D, tuple(cap)


def dp_offsets(first, config: SpeedConfig):
    """``(n_t,)`` int32 offsets ``hlo_k`` of the band from the reachable first-knot speeds
    (``first < unreach``)."""
    c = config
    H, D, cap = dp_band(c)
    jlo1 = jnp.argmax(first < unreach(c)).astype(jnp.int32)
    return jnp.stack(
        [jnp.minimum(_h_range(jlo1, jlo1 + D, k, c, jnp)[0], cap[k - 1]) for k in range(1, c.n_t + 1)]
    ).astype(jnp.int32)


@functools.cache
def _step_tables(config: SpeedConfig, k: int):
    """Static tables of the DP step into knot ``k`` (per target speed ``j'``, rows):
    ``(V, M (n_sub + 1) + M)`` int32 flat starts of the sub-step windows in the step's table
    block (``m``-major, then ``q``) and of the predecessor windows in the padded value block,
    and ``(V, M (n_sub + 1))`` the collision cost ``big (1 + v / COLLISION_V)`` of each sub-step."""
    c = config
    H, _, _ = dp_band(c)
    Hk, V, ns, offs = H[k - 1], c.n_v, c.n_sub, c.accel_offsets
    M = len(offs)
    R, SLOW, VQ = substep_tables(c)
    half = Hk + V - 1  # table block columns of one parity
    top = max(0, max(offs))
    starts = np.zeros((V, M * (ns + 1) + M), np.int32)
    K = np.zeros((V, M * (ns + 1)))
    for mi, om in enumerate(offs):
        for jp in range(V):
            j = jp - om  # speed at the segment's start (a padding row of big_u when out of range)
            starts[jp, M * (ns + 1) + mi] = (j + top) * half + min(max(V - 1 - j, 0), V - 1)
            jc = min(max(j, 0), V - 1)
            for q in range(ns + 1):
                y = int(R[jc, mi, q]) - jc + V - 1  # block column of the sub-step at h' = hlo
                starts[jp, mi * (ns + 1) + q] = ((y % 2 * 2 + int(SLOW[jc, mi, q])) * (ns + 1) + q) * half + y // 2
                K[jp, mi * (ns + 1) + q] = c.big * (1.0 + float(VQ[jc, mi, q]) / COLLISION_V)
    return starts, K


def _forward(d: DPCosts, config: SpeedConfig, temperature=None, probes=None):
    """Forward pass. Returns (final values ``(V, H_n)`` incl. terminal, argmins per step
    ``[(V, H_k)]`` int8 for k >= 2, band offsets ``(n_t,)``).

    **States.** ``h = j_1 + ... + j_{k-1}`` (the knot speeds before, in ``dv``): station
    ``i = 2 h + j`` (every reachable station has the parity of its speed), and a transition
    ``(h, j) -> (h + j, j')``. Values are rows per speed ``j``, each over the band's ``h``.

    **Reads.** For a target row ``j'`` and acceleration ``m`` the predecessors and every
    sub-step's table cells are contiguous runs (``i = 2 h' + const`` splits the table by
    parity) at offsets that depend on ``(j', m, q)`` only: per step the table block and
    the previous values are cut out once per plan (the band's dynamic offsets), then a
    ``scan`` over ``j'`` reads them with ``dynamic_slice`` at offsets shared by the whole
    batch (vectorised loops, no gathers), with every ``m`` and sub-step unrolled.
    """
    c = config
    H, _, _ = dp_band(c)
    offs = c.accel_offsets
    M, V, ns = len(offs), c.n_v, c.n_sub
    U0 = table_origin(c)
    big_u = unreach(c)
    dtype = d.table.dtype
    hlo = dp_offsets(d.first, c)
    z = jnp.zeros((), hlo.dtype)  # every start index int32 (also under x64)
    top, bot = max(0, max(offs)), max(0, -min(offs))

    def rows(src, k):  # (V, X) -> (V, H_k): src[j, U0 + 2 (hlo_k + a) + j]
        Hk = H[k - 1]
        blk = jax.lax.dynamic_slice(src, (z, U0 + 2 * hlo[k - 1]), (V, 2 * Hk + V))
        idx = np.arange(V)[:, None] * (2 * Hk + V + 1) + 2 * np.arange(Hk)[None, :]
        return blk.reshape(-1)[idx]

    def knot_cost(k):  # (V, H_k)
        nc = rows(d.node.T, k) + jnp.where(d.goal_k[k - 1], d.goal_v, 0.0)[:, None]
        return nc if probes is None else nc + probes[k - 1]

    val = jnp.minimum(d.first[:, None] + knot_cost(1), big_u)  # knot 1: h = 0
    accel = d.accel.astype(dtype)
    args = []
    for k in range(2, c.n_t + 1):
        Hk = H[k - 1]
        half = Hk + V - 1
        # previous values at h = hlo_k + a - j - (V - 1) + x, rows j = -top .. V - 1 + bot
        vp = jnp.pad(val, ((top, bot), (V - 1, Hk + V)), constant_values=big_u)
        pblk = jax.lax.dynamic_slice(vp, (z, hlo[k - 1] - hlo[k - 2]), (V + top + bot, half)).reshape(-1)
        # table block: check times (k-1) n_sub .. k n_sub, stations from 2 hlo_k - (V - 1), by parity
        tb = jax.lax.dynamic_slice(d.table, (z, z + (k - 1) * ns, U0 + 2 * hlo[k - 1] - (V - 1)), (2, ns + 1, 2 * half))
        tb = jnp.stack([tb[..., 0::2], tb[..., 1::2]]).reshape(-1)  # (parity, layer, q, half)
        inside = tb >= 0.5 * c.big
        rate = jnp.where(inside, tb - c.big, tb)
        starts, K = _step_tables(c, k)

        def body(_, xs, Hk=Hk, pblk=pblk, inside=inside, rate=rate):
            st, kq, nc = xs  # this target row's window starts, collision costs and knot costs
            tots = []
            for mi in range(M):
                obst, prev = None, None
                for q in range(ns + 1):
                    s = st[mi * (ns + 1) + q]
                    ins = jax.lax.dynamic_slice(inside, (s,), (Hk,))
                    if q > 0:  # segment_cost: the sub-step's rate, big on entering a boundary
                        enter = jnp.where(ins & ~prev, kq[mi * (ns + 1) + q], 0.0)
                        term = jax.lax.dynamic_slice(rate, (s,), (Hk,)) + enter
                        obst = term if obst is None else obst + term
                    prev = ins
                pred = jax.lax.dynamic_slice(pblk, (st[M * (ns + 1) + mi],), (Hk,))
                tots.append(pred + obst + accel[mi])
            if temperature is None:  # min over m, the first on ties (argmin)
                best, arg = tots[0], jnp.zeros((Hk,), jnp.int8)
                for mi in range(1, M):
                    better = tots[mi] < best
                    best, arg = jnp.where(better, tots[mi], best), jnp.where(better, jnp.int8(mi), arg)
            else:
                best = -temperature * jax.nn.logsumexp(-jnp.stack(tots) / temperature, 0)
                arg = jnp.zeros((Hk,), jnp.int8)
            return None, (jnp.minimum(best + nc, big_u), arg)

        # a scan over the target rows (the rows come out stacked; no carry to update in place)
        _, (val, arg) = jax.lax.scan(body, None, (jnp.asarray(starts), jnp.asarray(K, dtype), knot_cost(k)))
        args.append(arg)
    return val + rows(d.terminal.T, c.n_t), args, hlo


def _backtrack(final, args, hlo, config: SpeedConfig):
    """Station and speed indices ``(n_t,)`` at t_1..t_n and the total cost."""
    c = config
    Hn = dp_band(c)[0][-1]
    offs = jnp.asarray(c.accel_offsets)
    flat = jnp.argmin(final)
    cost = final.reshape(-1)[flat]
    j = (flat // Hn).astype(jnp.int32)
    h = hlo[-1] + (flat % Hn).astype(jnp.int32)
    hh, jj = [h], [j]
    for k in range(c.n_t, 1, -1):
        m = args[k - 2][j, h - hlo[k - 1]].astype(jnp.int32)
        jp = j - offs[m]
        h, j = h - jp, jp
        hh.append(h)
        jj.append(j)
    hs, js = jnp.stack(hh[::-1]), jnp.stack(jj[::-1])
    return 2 * hs + js, js, cost


def dp_from_costs(d: DPCosts, config: SpeedConfig):
    """Exact DP on given cost tensors. Returns (station idx ``(n_t,)`` at t_1..t_n, speed
    idx ``(n_t,)``, total cost)."""
    final, args, hlo = _forward(d, config)
    return _backtrack(final, args, hlo, config)


def soft_value(d: DPCosts, config: SpeedConfig, temperature, probes=None):
    """Soft-min DP value (a smooth lower bound of the DP optimum; equal as temperature -> 0).
    ``probes``: optional ``[(n_v, H_k)]`` added to the knot costs (``dp_band``)."""
    final, _, _ = _forward(d, config, temperature, probes)
    return -temperature * jax.nn.logsumexp(-final / temperature)


def profile_cost(d: DPCosts, config: SpeedConfig, j_seq):
    """Cost of one knot-speed sequence ``j_seq (n_t,)`` (host numpy loops, independent of the
    DP's band and windows: the brute-force reference). ``inf`` when not a valid profile."""
    c = config
    table, node, terminal = (np.asarray(a, np.float64) for a in (d.table, d.node, d.terminal))
    first, accel, gv, gk = (np.asarray(a, np.float64) for a in (d.first, d.accel, d.goal_v, d.goal_k))
    offs = list(c.accel_offsets)
    U0, X, ns = table_origin(c), table.shape[-1], c.n_sub
    j_seq = [int(j) for j in j_seq]
    if not 0 <= j_seq[0] < c.n_v or first[j_seq[0]] >= unreach(c):
        return np.inf
    i, cost = j_seq[0], first[j_seq[0]] + node[U0 + j_seq[0], j_seq[0]] + (gv[j_seq[0]] if gk[0] else 0.0)
    for k in range(1, c.n_t):
        j, j2 = j_seq[k - 1], j_seq[k]
        if j2 - j not in offs or not 0 <= j2 < c.n_v:
            return np.inf
        m = j2 - j
        inside_prev = None
        for q in range(0, ns + 1):
            u = min(max(U0 + i + int(np.round(2 * j * q / ns + m * (q / ns) ** 2)), 0), X - 1)
            v = (j + m * q / ns) * c.dv
            g = table[int(v < c.keep_clear_v), k * ns + q, u]
            inside = g >= 0.5 * c.big
            if q > 0:
                cost += g - c.big if inside else g
                if inside and not inside_prev:
                    cost += c.big * (1.0 + v / COLLISION_V)
            inside_prev = inside
        cost += accel[offs.index(m)]
        i = i + j + j2
        cost += node[min(U0 + i, X - 1), j2] + (gv[j2] if gk[k] else 0.0)
    return cost + terminal[min(U0 + i, X - 1), j_seq[-1]]


# ----------------------------------------------------------------------------- plans


def plan_one(
    path, obstacles, v0, a0, s0, keep_clear, road, vehicle, config, weights, buffer=None, merging=None, margin=None
) -> SpeedPlan:
    """The exact DP plan of one scene (unbatched, traceable: ``plan_speed`` checks, batches
    and jits it; a planner calls it inside its own program). Arguments as ``plan_speed``'s;
    ``buffer``: a traced clearance instead of ``config.buffer``; ``merging``: ``(K,)`` the
    obstacles moving over into the car's lane; ``margin``: ``()`` bool, keep the crossing margin
    (all three: ``st_graph.build_speed_scene``)."""
    _, scene = make_scene(path, obstacles, config, vehicle, s0, keep_clear, v0, road, buffer, merging, margin)
    d = stage_costs(scene, config, weights, v0, a0)
    ii, jj, cost = dp_from_costs(d, config)
    return _plan_from_indices(ii, jj, cost, d, v0, config, scene)


def _plan_from_indices(ii, jj, cost, d, v0, config, scene):
    dtype = d.table.dtype
    v0 = jnp.clip(jnp.asarray(v0, dtype), 0.0, config.v_max)
    s = jnp.concatenate([jnp.zeros((1,), dtype), d.c0 + ii.astype(dtype) * config.ds])
    v = jnp.concatenate([v0[None], jj.astype(dtype) * config.dv])
    t = jnp.arange(config.n_t + 1, dtype=dtype) * config.dt
    return SpeedPlan(t, s, v, jnp.diff(v) / config.dt, cost, cost < 0.5 * config.big, scene)


def expected_one(path, obstacles, v0, a0, s0, keep_clear, road, vehicle, config, weights, temperature) -> SpeedPlan:
    """The soft DP's expected plan of one scene (``expected_speed_profile``, unbatched)."""
    _, scene = make_scene(path, obstacles, config, vehicle, s0, keep_clear, v0, road)
    d = stage_costs(scene, config, weights, v0, a0)
    dtype = d.table.dtype
    H = dp_band(config)[0]
    probes = [jnp.zeros((config.n_v, Hk), dtype) for Hk in H]
    value, p = jax.value_and_grad(lambda pr: soft_value(d, config, temperature, pr))(probes)
    hlo = dp_offsets(d.first, config)
    j = jnp.arange(config.n_v, dtype=dtype)[:, None]
    es, ev = [], []
    for k, (pk, Hk) in enumerate(zip(p, H)):
        i = 2.0 * (hlo[k] + jnp.arange(Hk)).astype(dtype)[None, :] + j  # station index 2 h + j
        es.append(d.c0 + config.ds * jnp.sum(pk * i))
        ev.append(config.dv * jnp.sum(pk * j))
    v0c = jnp.clip(jnp.asarray(v0, dtype), 0.0, config.v_max)
    t = jnp.arange(config.n_t + 1, dtype=dtype) * config.dt
    s = jnp.concatenate([jnp.zeros((1,), dtype), jnp.stack(es)])
    v = jnp.concatenate([v0c[None], jnp.stack(ev)])
    return SpeedPlan(t, s, v, jnp.diff(v) / config.dt, value, value < 0.5 * config.big, scene)


BATCH_CHUNK = 100  # plans per vectorised chunk of a large leading batch


def map_batched(fn, batch_ndim, args):
    """``fn`` mapped over ``batch_ndim`` leading dims of ``args``: ``vmap``, except that a
    leading batch of more than ``BATCH_CHUNK`` plans runs as a loop over vmapped chunks of
    that many (``lax.map``): a plan's tables stay in the CPU's caches between the passes
    over them (``experiments/bench_speed.py``'s scenes, batch 1000, one process, load average
    3: 1,095 and 1,081 plans/s in one vmap, 1,438 and 1,244 in chunks of 100)."""
    if batch_ndim == 0:
        return fn(*args)
    f = fn
    for _ in range(batch_ndim - 1):
        f = jax.vmap(f)
    n = jax.tree_util.tree_leaves(args)[0].shape[0]
    if n > BATCH_CHUNK:
        return jax.lax.map(lambda a: f(*a), tuple(args), batch_size=BATCH_CHUNK)
    return jax.vmap(f)(*args)


def _check_inputs(path, obstacles, config, v0, weights):
    config.validate()
    if is_concrete(path, obstacles, v0):
        path.validate()
        obstacles.validate()
        if np.any(np.asarray(v0) < 0):
            raise ValueError("plan_speed: v0 must be >= 0")
    if weights is not None and is_concrete(weights):
        weights.validate()


def _prepare(path, obstacles, v0, a0, s0, road, weights):
    dtype = path.xy.dtype
    nb = path.xy.ndim - 2
    shape = path.xy.shape[:nb]
    v0, a0, s0 = (jnp.broadcast_to(jnp.asarray(x, dtype), shape) for x in (v0, a0, s0))
    weights = jax.tree_util.tree_map(lambda w: jnp.broadcast_to(jnp.asarray(w, dtype), shape), weights)
    if road is None:
        road = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, shape + x.shape), SpeedRoad.free(dtype))
    return nb, v0, a0, s0, road, weights


def _plan_impl(path, obstacles, v0, a0, s0, keep_clear, road, vehicle, weights, config):
    nb, v0, a0, s0, road, weights = _prepare(path, obstacles, v0, a0, s0, road, weights)
    fn = lambda p, o, v, a, s, kc, r, w: plan_one(p, o, v, a, s, kc, r, vehicle, config, w)
    return map_batched(fn, nb, (path, obstacles, v0, a0, s0, keep_clear, road, weights))


# the jitted kernel ``plan_speed`` dispatches to after its input checks
plan_speed_kernel = jax.jit(_plan_impl, static_argnames=("config",))


def plan_speed(
    path: ReferenceLine,
    obstacles: Obstacles,
    config: SpeedConfig = SpeedConfig(),
    weights: CostWeights | None = None,
    *,
    v0=0.0,
    a0=0.0,
    s0=0.0,
    keep_clear=None,
    vehicle: VehicleParams | None = None,
    road: SpeedRoad | None = None,
) -> SpeedPlan:
    """Exact DP speed plan along ``path``.

    Args:
        path: ``ReferenceLine`` with leading batch dims ``(..., P, 2)`` on its fields.
        obstacles: boxes ``(..., K, T, 5)``, valid ``(..., K, T)``, times ``(..., T)`` from now.
        config: grid and limits (static); weights: ``CostWeights``, each leaf a scalar
            (shared by the batch) or ``(...)`` (one per scene).
        v0, a0, s0: ``(...)`` current speed, acceleration and station on the path.
        keep_clear: optional ``(vertices (..., R, P, 2), valid (..., R, P), active (..., R))``.
        road: optional ``SpeedRoad`` with leading dims ``(...)`` (speed limit, stop, goal).

    Returns:
        ``SpeedPlan`` with leading dims ``(...)``.
    """
    _check_inputs(path, obstacles, config, v0, weights)
    weights = CostWeights.default(path.xy.dtype) if weights is None else weights
    vehicle = VehicleParams() if vehicle is None else vehicle
    return plan_speed_kernel(path, obstacles, v0, a0, s0, keep_clear, road, vehicle, weights, config)


def _expected_impl(path, obstacles, v0, a0, s0, keep_clear, road, vehicle, weights, temperature, config):
    nb, v0, a0, s0, road, weights = _prepare(path, obstacles, v0, a0, s0, road, weights)
    fn = lambda p, o, v, a, s, kc, r, w: expected_one(p, o, v, a, s, kc, r, vehicle, config, w, temperature)
    return map_batched(fn, nb, (path, obstacles, v0, a0, s0, keep_clear, road, weights))


_expected_jit = jax.jit(_expected_impl, static_argnames=("config",))


def expected_speed_profile(
    path: ReferenceLine,
    obstacles: Obstacles,
    config: SpeedConfig = SpeedConfig(),
    weights: CostWeights | None = None,
    temperature=1.0,
    *,
    v0=0.0,
    a0=0.0,
    s0=0.0,
    keep_clear=None,
    vehicle: VehicleParams | None = None,
    road: SpeedRoad | None = None,
) -> SpeedPlan:
    """Smooth (soft-min) DP: the expected knot station and speed under the Gibbs
    distribution of speed profiles ``p ~ exp(-cost / temperature)``.

    Differentiable in ``weights`` (for tuning against recorded profiles); as the
    temperature goes to 0 it becomes the exact DP's profile. Same arguments as
    ``plan_speed``; ``cost`` holds the soft value.
    """
    _check_inputs(path, obstacles, config, v0, weights)
    weights = CostWeights.default(path.xy.dtype) if weights is None else weights
    vehicle = VehicleParams() if vehicle is None else vehicle
    return _expected_jit(
        path, obstacles, v0, a0, s0, keep_clear, road, vehicle, weights, jnp.asarray(temperature, path.xy.dtype), config
    )
