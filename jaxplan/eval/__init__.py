"""Evaluation suites, the registry the CLI dispatches on, metrics and plots."""

from jaxplan.eval.registry import SUITES, register, run_suite

__all__ = ["SUITES", "register", "run_suite"]
