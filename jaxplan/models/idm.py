"""The Intelligent Driver Model (Treiber, Hennecke, Helbing 2000): the acceleration of one
vehicle following a leader on a lane.

``idm_accel`` is the one IDM formula of the library. Its users bring their own parameter
values: the ``idm`` baseline planner (``jaxplan.baselines.idm``), the imitation baseline of the
tuning suite (``jaxplan.tuning.traffic``) and the simulator's reactive agents
(``jaxplan.sim.agents``).
"""

from __future__ import annotations

import jax.numpy as jnp

MIN_DESIRED_SPEED = 0.1  # m/s: the desired speed in the free-road term is floored here
MIN_GAP = 0.1  # m: the gap in the interaction term is floored here (finite values and gradients)


def idm_accel(v, v_des, gap, dv, *, a_max, b_comf, time_gap, min_gap, delta=4.0, has_leader=True):
    """IDM acceleration (m/s^2) of one vehicle, unclipped:

    ``a_max * (1 - (v / v_des)^delta - (s* / gap)^2)`` with the desired gap
    ``s* = min_gap + max(0, v * time_gap + v * dv / (2 sqrt(a_max * b_comf)))``; the
    interaction term is dropped where there is no leader. ``v`` is floored at 0, ``v_des`` at
    ``MIN_DESIRED_SPEED`` and ``gap`` at ``MIN_GAP`` (so values and gradients stay finite).
    Every argument broadcasts: shapes ``(...)``, batch with ``vmap`` or broadcasting; callers
    clip the result to their own braking and acceleration limits.

    Args:
        v: ``(...)`` speed (m/s).
        v_des: ``(...)`` desired speed (m/s).
        gap: ``(...)`` bumper-to-bumper distance to the leader (m).
        dv: ``(...)`` approach rate ``v - v_leader`` (m/s).
        a_max: maximum acceleration (m/s^2).
        b_comf: comfortable deceleration (m/s^2, > 0).
        time_gap: desired time headway (s).
        min_gap: jam distance (m).
        delta: acceleration exponent.
        has_leader: ``(...)`` bool; where False the acceleration is the free-road term alone.

    Returns:
        ``(...)`` the acceleration.
    """
    free = 1.0 - (jnp.maximum(v, 0.0) / jnp.maximum(v_des, MIN_DESIRED_SPEED)) ** delta
    s_star = min_gap + jnp.maximum(0.0, v * time_gap + v * dv / (2.0 * jnp.sqrt(a_max * b_comf)))
    inter = jnp.where(has_leader, (s_star / jnp.maximum(gap, MIN_GAP)) ** 2, 0.0)
    return a_max * (free - inter)
