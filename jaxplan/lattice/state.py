"""The car's state a lattice plan starts from (``PlanState``): position, heading, curvature, speed,
acceleration, set speed and the distance to the next crossroad."""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxplan.types import check_coordinates, check_finite, pytree_dataclass


@pytree_dataclass(data_fields=("x", "y", "heading", "kappa", "v", "a", "v_set", "d_crossroad"))
class PlanState:
    """The car's state, each field ``(...)``.

    ``v_set`` is the set (cruise) speed; ``d_crossroad`` the distance along the
    reference line to the next crossroad (``inf`` when there is none).
    """

    x: Any
    y: Any
    heading: Any
    kappa: Any = 0.0
    v: Any = 0.0
    a: Any = 0.0
    v_set: Any = None
    d_crossroad: Any = float("inf")

    @classmethod
    def make(cls, x, y, heading, v, a=0.0, kappa=0.0, v_set=None, d_crossroad=float("inf")) -> PlanState:
        """Host-side constructor with checks; ``v_set`` defaults to ``v``."""
        f = jnp.result_type(float)
        st = cls(*(jnp.asarray(z, f) for z in (x, y, heading, kappa, v, a, v if v_set is None else v_set, d_crossroad)))
        return st.validate()

    @classmethod
    def from_rows(cls, ego) -> PlanState:
        """Jittable: states from rows ``ego (..., 5)`` = [x, y, heading, v, a] (the layout of
        ``jaxplan.scenarios.synthetic`` and ``jaxplan.tuning.demos``): no curvature, the set
        speed is the current speed, no crossroad."""
        e = jnp.asarray(ego)
        zero = jnp.zeros_like(e[..., 0])
        return cls(e[..., 0], e[..., 1], e[..., 2], zero, e[..., 3], e[..., 4], e[..., 3], zero + jnp.inf)

    def validate(self) -> PlanState:
        for name in ("x", "y", "heading", "kappa", "v", "a", "v_set"):
            check_finite(f"PlanState.{name}", getattr(self, name))
        check_coordinates("PlanState x, y", np.stack(np.broadcast_arrays(np.asarray(self.x), np.asarray(self.y)), -1))
        if np.any(np.asarray(self.v) < 0):
            raise ValueError("PlanState.v must be >= 0")
        if np.any(np.isnan(np.asarray(self.d_crossroad))):
            raise ValueError("PlanState.d_crossroad is NaN (use inf for no crossroad)")
        return self
