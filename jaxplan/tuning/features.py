"""Scene-by-candidate features for a cost that can imitate human drivers.

The lattice's own cost (``jaxplan.lattice.cost``) ranks candidates by lane offset,
curvature and the change from the set speed, which is the current speed: nothing
in it depends on the traffic ahead, so it cannot say when a human slows down for a
closing gap or speeds up into a free one. The features here are computed from any
lattice's public ``Candidates`` (trajectories, Frenet ``s`` and ``l``, lane, end
speed) and the scene (the other vehicles in the reference line's Frenet frame), so
they keep working when the lattice gains end times, lateral times or modes.

Features ``(..., N, F)`` in the order of ``FEATURES``; most are means over the first
``window`` seconds (the 3 s of the ADE3 metric), sampled every ``every`` steps. Signed
ones (``SIGNED``) may take a weight of either sign:

- ``d_lrp``: mean ``|l - l_target|`` (m), distance to the current lane's centre.
- ``lane_change``: ``|lane|``, 1 for a candidate ending in a neighbour lane.
- ``lane_side`` (signed): ``lane`` (+1 left, -1 right).
- ``lane_offset``: ``|offset - lane * lane_width|`` (m), where in its lane it ends (lane keeping).
- ``curvature``: ``max |kappa|`` over the horizon (1/m).
- ``lat_accel``: mean ``(v^2 kappa)^2`` (m^2/s^4).
- ``accel``: mean ``a^2`` (m^2/s^4); ``jerk``: mean ``(da/dt)^2`` (m^2/s^6).
- ``speed_change`` (signed): ``v_end - v0`` (m/s); ``speed_change_abs``: ``|v_end - v0|``.
- ``headway``: mean ``1 / max(THW, thw_floor)`` (1/s), THW = gap to the vehicle ahead
  of the candidate (in its lane band) over its speed; 0 while nobody is ahead.
- ``closing``: mean ``relu(v - v_leader)^2 / (2 max(gap, 1 m))`` (m/s^2), the braking
  needed to match the leader's speed before reaching it.
- ``progress_dev``: mean ``(s - s_desired)^2`` (m^2), ``s_desired`` the desired progress
  in the candidate's lane: the IDM car behind that lane's recorded leader
  (``traffic.idm_rollout``), so the leader's gap and speed set it;
  ``progress_dev_late``: the same after ``window`` (to the horizon);
  ``progress_ahead`` (signed): mean ``s - s_desired`` (m).
- ``cv_dev``: mean ``(s - v0 t)^2`` (m^2), the distance from keeping the speed;
  ``cv_ahead`` (signed): mean ``s - v0 t`` (m); ``free_cv_dev``: ``cv_dev`` when nobody
  leads the car at the start (then the desired progress is only a guess of the free speed).
- ``risk``: ``1 / max(TTC, ttc_min)`` (1/s), 0 without collision (the lattice's feature).

Squared distances to several progress targets add up to the squared distance to a
weighted mean of them, so the learned weights also learn how far to trust the
car-following model and how far to keep the speed, and the signed terms shift the
target ahead or behind.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.lattice.candidates import Candidates
from jaxplan.lattice.config import LatticeConfig
from jaxplan.tuning.traffic import FrenetTraffic, IDMParams, idm_rollout, leader

FEATURES = (
    "d_lrp",
    "lane_change",
    "lane_side",
    "lane_offset",
    "curvature",
    "lat_accel",
    "accel",
    "jerk",
    "speed_change",
    "speed_change_abs",
    "headway",
    "closing",
    "progress_dev",
    "progress_dev_late",
    "progress_ahead",
    "cv_dev",
    "cv_ahead",
    "free_cv_dev",
    "risk",
)
SIGNED = frozenset({"lane_side", "speed_change", "progress_ahead", "cv_ahead"})
UNITS = {
    "d_lrp": "m",
    "lane_change": "-",
    "lane_side": "-",
    "lane_offset": "m",
    "curvature": "1/m",
    "lat_accel": "m^2/s^4",
    "accel": "m^2/s^4",
    "jerk": "m^2/s^6",
    "speed_change": "m/s",
    "speed_change_abs": "m/s",
    "headway": "1/s",
    "closing": "m/s^2",
    "progress_dev": "m^2",
    "progress_dev_late": "m^2",
    "progress_ahead": "m",
    "cv_dev": "m^2",
    "cv_ahead": "m",
    "free_cv_dev": "m^2",
    "risk": "1/s",
}


@dataclasses.dataclass(frozen=True)
class FeatureConfig:
    """Static settings of the features.

    Attributes:
        every: sample every ``every`` steps of the candidates (the means run over those).
        window: seconds the means run over (``progress_dev_late``: the rest of the horizon).
        car_length: the car's length for gaps (m).
        band: lateral half-width (m) within which a vehicle is ahead in a lane.
        thw_floor: time headway floor (s) of ``headway``.
        ttc_min: TTC floor (s) of ``risk``.
    """

    every: int = 2
    window: float = 3.0
    car_length: float = 4.8
    band: float = 1.75
    thw_floor: float = 0.5
    ttc_min: float = 0.1


def candidate_features(
    cand: Candidates,
    ttc,
    traffic: FrenetTraffic,
    v0,
    config: LatticeConfig,
    idm: IDMParams = IDMParams(),
    fcfg: FeatureConfig = FeatureConfig(),
):
    """Features ``(N, F)`` of one scene's candidates (``jax.vmap`` for batches).

    Args:
        cand: ``Candidates`` of one plan (fields ``(N, T)`` / ``(N,)``).
        ttc: ``(N,)`` time to collision (inf = none), e.g. ``LatticeResult.ttc``.
        traffic: the other vehicles ``(K, T)`` on the candidates' time grid
            (``traffic.frenet_traffic`` of the aligned obstacles).
        v0: ``()`` start speed (m/s).
        config: the lattice's settings (lanes, lane width, dt).
        idm: parameters of the desired-progress model.
    """
    e = fcfg.every
    dt = config.dt * e
    s_all = cand.s - cand.s[:, :1]  # (N, T) progress along the line
    s, l = s_all[:, ::e], cand.l[:, ::e]
    v, a, kappa = cand.traj.v[:, ::e], cand.traj.a[:, ::e], cand.traj.kappa[:, ::e]
    tr = FrenetTraffic(
        *(f[:, ::e] for f in (traffic.s, traffic.l, traffic.v, traffic.length, traffic.width, traffic.valid))
    )
    s_start = cand.s[0, 0]
    t = jnp.arange(s.shape[-1], dtype=s.dtype) * dt
    early = (t > 0) & (t <= fcfg.window + 1e-6)
    late = t > fcfg.window + 1e-6
    mean = lambda x, w=early: jnp.sum(jnp.where(w, x, 0.0), -1) / jnp.maximum(jnp.sum(w), 1)
    d_lrp = mean(jnp.abs(l - cand.l_target))
    lane = cand.lane.astype(s.dtype)
    lane_off = jnp.abs(cand.offset - lane * config.lane_width)
    rho = jnp.max(jnp.abs(cand.traj.kappa), axis=-1)
    lat = mean((v * v * kappa) ** 2)
    acc = mean(a * a)
    jerk = mean(jnp.concatenate([jnp.zeros_like(a[:, :1]), (a[:, 1:] - a[:, :-1]) / dt], -1) ** 2)
    dv = cand.v_end - v0
    gap, v_lead, has = leader(tr, s + s_start, l, fcfg.car_length, fcfg.band)
    thw = gap / jnp.maximum(v, 1.0)
    headway = mean(jnp.where(has, 1.0 / jnp.maximum(thw, fcfg.thw_floor), 0.0))
    closing = mean(jnp.where(has, jnp.maximum(v - v_lead, 0.0) ** 2 / (2.0 * jnp.maximum(gap, 1.0)), 0.0))
    # desired progress in each lane of the lattice: the IDM car behind that lane's leader
    lanes = jnp.asarray(config.lanes, s.dtype)
    s_des = (
        jax.vmap(
            lambda ln: idm_rollout(tr, s_start, ln * config.lane_width, v0, fcfg.car_length, idm, dt, fcfg.band)[0]
        )(lanes)
        - s_start
    )  # (Ln, T')
    which = jnp.argmax(cand.lane[:, None] == jnp.asarray(config.lanes)[None], axis=-1)
    dev = s - s_des[which]
    cv = s - v0 * t
    # is anybody ahead of the car in its own lane at the start?
    _, _, led = leader(tr, jnp.full((1, 1), s_start), jnp.zeros((1, 1), s.dtype), fcfg.car_length, fcfg.band)
    cv_dev = mean(cv * cv)
    risk = jnp.where(jnp.isfinite(ttc), 1.0 / jnp.maximum(ttc, fcfg.ttc_min), 0.0)
    cols = dict(
        d_lrp=d_lrp,
        lane_change=jnp.abs(lane),
        lane_side=lane,
        lane_offset=lane_off,
        curvature=rho,
        lat_accel=lat,
        accel=acc,
        jerk=jerk,
        speed_change=dv,
        speed_change_abs=jnp.abs(dv),
        headway=headway,
        closing=closing,
        progress_dev=mean(dev * dev),
        progress_dev_late=mean(dev * dev, late),
        progress_ahead=mean(dev),
        cv_dev=cv_dev,
        cv_ahead=mean(cv),
        free_cv_dev=jnp.where(led[0, 0], 0.0, cv_dev),
        risk=risk,
    )
    return jnp.stack([cols[k] for k in FEATURES], axis=-1)


def signed_mask(names=FEATURES) -> np.ndarray:
    """``(F,)`` bool: which features have a signed weight."""
    return np.array([n in SIGNED for n in names])
