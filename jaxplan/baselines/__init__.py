"""Baseline road planners: in-lane braking and lane-keeping IDM (the references every
planner is compared with, and the survivability test of generated scenes)."""

from jaxplan.baselines.brake import BrakePlanner
from jaxplan.baselines.idm import IDMParams, IDMPlanner, idm_accel

__all__ = ["BrakePlanner", "IDMPlanner", "IDMParams", "idm_accel"]
