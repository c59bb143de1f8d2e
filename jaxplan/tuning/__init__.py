"""Cost weights learned by gradient: from recorded human driving (imitation, with optax) and through
closed-loop drives (``closed_loop``: ``jaxplan tune --closed-loop``).

Its modules load on first use (they import optax and the planners): ``jaxplan.tuning.closed_loop``,
``from jaxplan.tuning import lattice_tuning``.
"""

__all__ = [
    "baselines",
    "closed_loop",
    "demos",
    "features",
    "imitation",
    "lattice_tuning",
    "metrics",
    "run",
    "speed_tuning",
    "traffic",
    "train",
    "vehicles",
]


def __getattr__(name):
    if name in __all__:
        import importlib

        return importlib.import_module(f"jaxplan.tuning.{name}")
    raise AttributeError(f"module 'jaxplan.tuning' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
