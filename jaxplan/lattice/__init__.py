"""Quintic candidate lattice with velocity profiles, time-aware collision risk and cost selection."""

from jaxplan.geometry.quintic import cartesian_to_frenet_state, quintic_coeffs, quintic_eval
from jaxplan.lattice.candidates import Candidates, generate
from jaxplan.lattice.config import KMH, LatticeConfig
from jaxplan.lattice.cost import (
    CONSTRAINED,
    EMERGENCY,
    ESCALATED,
    FEATURES,
    FREE,
    INVALID,
    MODE_NAMES,
    RISK,
    CostWeights,
    choose,
    cost_features,
    costs,
    lam,
    select,
    soft_select,
)
from jaxplan.lattice.crossroad import stop_box, with_stop_target
from jaxplan.lattice.plan import LatticeResult, plan, plan_batch
from jaxplan.lattice.profiles import accel_profile, jerk_profile, jerk_profile_params
from jaxplan.lattice.risk import (
    Risk,
    align_obstacles,
    collision_risk,
    min_separation,
    risk_from_separation,
    trajectory_boxes,
)
from jaxplan.lattice.state import PlanState

__all__ = [
    "KMH",
    "Candidates",
    "LatticeConfig",
    "PlanState",
    "generate",
    "CONSTRAINED",
    "EMERGENCY",
    "ESCALATED",
    "FEATURES",
    "FREE",
    "INVALID",
    "MODE_NAMES",
    "RISK",
    "CostWeights",
    "choose",
    "cost_features",
    "costs",
    "lam",
    "select",
    "soft_select",
    "stop_box",
    "with_stop_target",
    "LatticeResult",
    "plan",
    "plan_batch",
    "accel_profile",
    "jerk_profile",
    "jerk_profile_params",
    "cartesian_to_frenet_state",
    "quintic_coeffs",
    "quintic_eval",
    "Risk",
    "align_obstacles",
    "collision_risk",
    "min_separation",
    "risk_from_separation",
    "trajectory_boxes",
]
