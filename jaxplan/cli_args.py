"""Argument types and checks shared by the ``jaxplan`` subcommands.

Each check is a plain function ``text -> value`` usable as an argparse ``type=``: a bad
value raises ``BadArgument`` (an ``argparse.ArgumentTypeError`` and a ``ValueError``) whose
message names the value and says what is wrong. ``ArgumentParser`` turns every usage error
into one line, ``jaxplan: error: argument --n: must be a positive integer, got '-1'``, and
exit status 2 (see ``parse``). Nothing here imports JAX or compiles anything, so a bad
argument is refused before any heavy work; the scenario checks import the (numpy) loader.

Usage in a subcommand::

    sub.add_parser("drive", ...).add_argument("scenario", type=cli_args.scenario_file)
"""

from __future__ import annotations

import argparse
import os
import sys

from jaxplan.weights import HANDSET


class BadArgument(argparse.ArgumentTypeError, ValueError):
    """A bad argument value; the message names it."""


class UsageError(Exception):
    """A command line that cannot be run (exit status 2); ``str()`` is the one-line message."""


class ArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose errors raise ``UsageError`` instead of printing usage and exiting."""

    def error(self, message):
        raise UsageError(message)


def parse(parser: argparse.ArgumentParser, argv, prog: str = "jaxplan"):
    """``parser.parse_args(argv)``; returns ``(args, None)`` or ``(None, exit status)`` after printing
    one error line (status 2) or the help / version text (status 0)."""
    try:
        return parser.parse_args(argv), None
    except UsageError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return None, 2
    except SystemExit as e:  # --help, --version
        return None, int(e.code or 0)


def _number(text, cast, ok, what: str):
    """``cast(text)`` when it parses and ``ok`` holds for it, else ``BadArgument("must be <what>")``."""
    try:
        v = cast(text)
    except (TypeError, ValueError):
        raise BadArgument(f"must be {what}, got {text!r}") from None
    if not ok(v):
        raise BadArgument(f"must be {what}, got {text!r}")
    return v


def positive_int(text) -> int:
    """An integer >= 1."""
    return _number(text, int, lambda v: v >= 1, "a positive integer")


def nonnegative_int(text) -> int:
    """An integer >= 0."""
    return _number(text, int, lambda v: v >= 0, "an integer >= 0")


def existing_file(text) -> str:
    """A path to a readable file (not a folder)."""
    path = str(text)
    if not os.path.exists(path):
        raise BadArgument(f"{path}: no such file")
    if os.path.isdir(path):
        raise BadArgument(f"{path}: is a folder, not a file")
    if not os.access(path, os.R_OK):
        raise BadArgument(f"{path}: not readable")
    return path


def positive_float(text) -> float:
    """A finite number > 0."""
    return _number(text, float, lambda v: 0 < v < float("inf"), "a positive number")


def existing_path(text) -> str:
    """A path to an existing file or folder."""
    path = str(text)
    if not os.path.exists(path):
        raise BadArgument(f"{path}: no such file or folder")
    return path


def existing_dir(text) -> str:
    """A path to an existing folder."""
    path = str(text)
    if not os.path.exists(path):
        raise BadArgument(f"{path}: no such folder")
    if not os.path.isdir(path):
        raise BadArgument(f"{path}: is a file, not a folder")
    return path


def scenario_dir(text) -> str:
    """A folder with at least one scenario file that loads (the shared JSON or CommonRoad XML,
    either gzip-compressed; its sub-folders too).

    Only the first loadable file is read, so the check stays cheap; the suites load the rest
    and name every file that fails (``jaxplan.scenarios.files.load_folder``)."""
    path = existing_dir(text)
    from jaxplan.scenarios.fields import ScenarioError
    from jaxplan.scenarios.files import first_loadable

    try:
        first_loadable(path)
    except ScenarioError as e:
        raise BadArgument(str(e)) from None
    return path


SCENARIO_SUFFIXES = (".json", ".xml")


def scenario_dirs(text) -> str:
    """Comma-separated folders of scenario files, each checked as ``scenario_dir`` (a folder of
    CommonRoad XML only: that it has a ``.xml`` file; the suites that read XML load it)."""
    parts = [p for p in str(text).split(",") if p]
    if not parts:
        raise BadArgument(f"{text!r}: no folder named")
    import glob

    for p in parts:
        existing_dir(p)
        if glob.glob(os.path.join(p, "*.json")) or not glob.glob(os.path.join(p, "*.xml")):
            scenario_dir(p)
    return str(text)


def scenario_file(text) -> str:
    """A scenario file: shared JSON (``.json``) or CommonRoad XML (``.xml``) that exists."""
    path = existing_file(text)
    if not path.lower().endswith(SCENARIO_SUFFIXES):
        raise BadArgument(f"{path}: not a scenario file (expected {' or '.join(SCENARIO_SUFFIXES)})")
    return path


def _parent_ok(path: str) -> None:
    parent = os.path.dirname(os.path.abspath(path))
    while parent and not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if parent and not os.path.isdir(parent):
        raise BadArgument(f"{path}: {parent} is a file, not a folder")
    if parent and not os.access(parent, os.W_OK):
        raise BadArgument(f"{path}: cannot write into {parent}")


def output_dir(text) -> str:
    """An output folder: an existing folder, or a path that can be created (not an existing file)."""
    path = str(text)
    if not path:
        raise BadArgument("empty path")
    if os.path.exists(path):
        if not os.path.isdir(path):
            raise BadArgument(f"{path}: is a file, not an output folder")
        if not os.access(path, os.W_OK):
            raise BadArgument(f"{path}: cannot write into this folder")
        return path
    _parent_ok(path)
    return path


def output_file(text) -> str:
    """A file to write: not an existing folder, and its folder can be created."""
    path = str(text)
    if not path:
        raise BadArgument("empty path")
    if os.path.isdir(path):
        raise BadArgument(f"{path}: is a folder, not a file")
    _parent_ok(path)
    return path


def weights_file_or_handset(text) -> str:
    """``jaxplan drive --weights``: an existing weights file, or the name ``handset`` (every planner's
    built-in, hand-set weights); the file's content is checked per planner by the command."""
    if str(text) == HANDSET:
        return HANDSET
    if not os.path.exists(str(text)):
        raise BadArgument(f"{text}: no such file, and not the name {HANDSET!r} (every planner's built-in weights)")
    return existing_file(text)


def weights_file(planner: str):
    """Type for ``--weights``: an existing weights file of ``planner`` with only its weight names."""

    def check(text) -> str:
        path = existing_file(text)
        try:
            if planner == "lattice":  # the lattice rule's weights or an imitation model (`jaxplan tune lattice`)
                from jaxplan.tuning.run import load_cost

                load_cost(path)
            else:
                from jaxplan.tuning.speed_tuning import default_speed_weights
                from jaxplan.weights import load_weights

                load_weights(path, allowed=tuple(default_speed_weights()), planner=planner)
        except ValueError as e:
            raise BadArgument(str(e)) from None
        return path

    check.__name__ = f"{planner}_weights_file"
    return check
