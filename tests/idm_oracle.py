"""One step of the Intelligent Driver Model in plain Python: the test oracle of the ``idm``
baseline and of the tuning demonstrations (independent of the JAX code they check)."""
import math


def idm_step(s: float, v: float, v_des: float, p, dt: float, gap: float | None = None, v_lead: float = 0.0,
             min_gap: float = -math.inf) -> tuple[float, float]:
    """``(s, v)`` after one step of ``dt`` from station ``s`` and speed ``v``, with IDM parameters
    ``p`` (``IDMParams`` fields), desired speed ``v_des`` and, when ``gap`` is given, a leader
    that far ahead (bumper to bumper, at least ``min_gap``) at ``v_lead``; acceleration floored
    at -8 m/s^2, speed at 0, position by the trapezoid rule."""
    a_free = 1 - (v / v_des) ** p.delta
    if gap is None:
        a = p.a_max * a_free
    else:
        s_star = p.s_jam + max(0.0, v * p.headway + v * (v - v_lead) / (2 * math.sqrt(p.a_max * p.b_comf)))
        a = p.a_max * (a_free - (s_star / max(gap, min_gap)) ** 2)
    a = max(a, -8.0)
    v_new = max(v + a * dt, 0.0)
    return s + 0.5 * (v + v_new) * dt, v_new
