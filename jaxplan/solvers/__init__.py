"""Solvers shared by the planners: one QP solver (OSQP's ADMM, ``qp``) and the small linear
algebra it and the path QP's polishing run on (``linalg``)."""

from jaxplan.solvers.linalg import block_factor, block_solve, cholesky, lower_inverse, small_inverse, spd_inverse
from jaxplan.solvers.qp import (
    ADMMSettings,
    LadderSettings,
    Prefactored,
    adapted_rho,
    admm_iterations,
    admm_prefactored,
    admm_solve,
    prefactor,
    residuals,
    ruiz,
)

__all__ = [
    "ADMMSettings",
    "LadderSettings",
    "Prefactored",
    "adapted_rho",
    "admm_iterations",
    "admm_prefactored",
    "admm_solve",
    "block_factor",
    "block_solve",
    "cholesky",
    "lower_inverse",
    "prefactor",
    "residuals",
    "ruiz",
    "small_inverse",
    "spd_inverse",
]
