"""The peer harness behind ``experiments/compare_peers.py`` (its docstring: what runs where, the
setup, the outputs), one module per job:

- ``config``: paths, the peers' interpreters, the route builder, the car, the step;
- ``files``: CommonRoad XML in (also gzip), JSON out;
- ``workers``: the jobs run as child processes in the peers' and the referee's environments
  (scenario facts, routes, one peer's drive, the referee), and ``worker_main``, which runs one;
- ``closed_loop``: what both peers' closed loops share (driven rows, the fallback brake, the goal
  check, the route they follow);
- ``frenetix_loop``: Frenetix's sampling loop around the ``frenetix`` package;
- ``harness``: the command line, the file selection, the child processes, resuming, ``main``;
- ``settings``: the table of the settings that differ between the planners and those that are equal;
- ``summary``: counts, jaxplan's own verdict, its agreement with the referee, plan times;
- ``report``: ``report.md`` and the plots.

``config``, ``files``, ``closed_loop``, ``frenetix_loop`` and ``workers`` import only the standard
library and numpy at import time (the peers' environments have no jaxplan); so do the others,
which import jaxplan inside the functions that use it.
"""
