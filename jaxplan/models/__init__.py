"""Vehicle models shared by the planners, the simulator and the tuning suite: one
implementation of each (``idm``: the Intelligent Driver Model)."""

from jaxplan.models.idm import idm_accel

__all__ = ["idm_accel"]
