"""Seeded random closed-loop scenarios (numpy, host side): parking approaches and short drives.

Parking approach: the car starts at the origin heading +x along an aisle; the
slot lies to the right, ``gx`` metres ahead, and the car reverses into it
(goal heading +pi/2). The goal observation has a bias (up to ``max_bias`` m)
that fades as the car nears the slot, plus noise. Short drive: a forward stop
``25..35`` m ahead, unbiased noisy goal. Obstacles are placed on the nominal
plan (the planner's plan to the true goal): a real static box beside the path
(probability ``p_real``), up to two phantoms on it (``p_phantom`` each) and a
pedestrian that crosses it (``p_dyn``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.replan.path_planner import ApproachPlanner, nominal_forward_path
from jaxplan.replan.simulator import ManeuverScenario

R, P, D = 1, 2, 1


def sample_scenarios(
    seed: int,
    n: int,
    kind: str = "park",
    planner: ApproachPlanner = ApproachPlanner(),
    max_bias: float = 0.8,
    p_real: float = 0.5,
    p_phantom: float = 0.6,
    p_dyn: float = 0.35,
    goal_sigma: float = 0.15,
    yaw_sigma: float = 0.02,
) -> ManeuverScenario:
    """``n`` scenarios of ``kind`` ``"park"`` or ``"drive"``, stacked on a leading axis.

    Goal noise: ``goal_sigma`` m (drives: at most 0.1) and ``yaw_sigma`` rad per observation;
    the bias far from the slot is ``0.3 .. max_bias`` m (parking only)."""
    if kind not in ("park", "drive"):
        raise ValueError(f"kind must be 'park' or 'drive', got {kind!r}")
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    rng = np.random.default_rng(seed)
    park = kind == "park"
    out = []
    keys = np.asarray(jax.random.split(jax.random.PRNGKey(seed), n))
    for i in range(n):
        start = np.array([0.0, 0.0, 0.0])
        if park:
            goal = np.array([rng.uniform(14, 20), -7 + rng.uniform(-0.2, 0.2), np.pi / 2 + rng.uniform(-0.05, 0.05)])
            ang = rng.uniform(0, 2 * np.pi)
            mag = rng.uniform(min(0.3, max_bias), max_bias)
            bias = np.array([mag * np.cos(ang), mag * np.sin(ang), rng.uniform(-0.06, 0.06)])
        else:
            goal = np.array([rng.uniform(25, 35), rng.uniform(-0.5, 0.5), rng.uniform(-0.05, 0.05)])
            bias = np.zeros(3)
        xy = nominal_forward_path(planner, start, goal, park)
        d = np.diff(xy, axis=0)
        th = np.arctan2(d[:, 1], d[:, 0])

        def on_path(lo, hi):
            j = int(rng.uniform(lo, hi) * (len(th) - 1))
            return xy[j], th[j]

        p, h = on_path(0.45, 0.75)
        lat = rng.uniform(-0.6, 0.6)
        real = np.array([[p[0] - lat * np.sin(h), p[1] + lat * np.cos(h), 1.2, 1.0, h + rng.uniform(-0.3, 0.3)]])
        real_valid = np.array([rng.uniform() < p_real])
        ph, ph_valid = [], []
        for _ in range(P):
            p, h = on_path(0.3, 0.9)
            ph.append([p[0], p[1], 0.8, 0.8, 0.0])
            ph_valid.append(rng.uniform() < p_phantom)
        p, h = on_path(0.35, 0.8)
        sgn = rng.choice([-1.0, 1.0])
        dyn_dir = sgn * np.array([[-np.sin(h), np.cos(h)]])
        out.append(
            ManeuverScenario(
                start=start,
                goal=goal,
                park=np.array(park),
                goal_bias=bias,
                goal_sigma=np.array(goal_sigma if park else min(goal_sigma, 0.1)),
                yaw_sigma=np.array(yaw_sigma),
                real=real,
                real_valid=real_valid,
                phantom=np.array(ph),
                phantom_valid=np.array(ph_valid),
                phantom_range=rng.uniform(6, 10, P),
                phantom_dur=rng.uniform(0.2, 1.0, P),
                dyn_point=p[None],
                dyn_dir=dyn_dir,
                dyn_speed=rng.uniform(1.0, 1.5, D),
                dyn_size=np.array([[0.6, 0.6]]),
                dyn_range=rng.uniform(9, 13, D),
                dyn_valid=np.array([rng.uniform() < p_dyn]),
                key=keys[i],
            )
        )
    stacked = jax.tree.map(lambda *a: np.stack(a), *out)
    return jax.tree.map(lambda a: jnp.asarray(a, jnp.float32) if a.dtype == np.float64 else jnp.asarray(a), stacked)
