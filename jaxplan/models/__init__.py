"""Vehicle models shared by the planners, the simulator and the tuning suite: one
implementation of each (``idm``: the Intelligent Driver Model; ``braking``: braking at a constant
deceleration to a stop)."""

from jaxplan.models.braking import braking_profile
from jaxplan.models.idm import idm_accel

__all__ = ["braking_profile", "idm_accel"]
