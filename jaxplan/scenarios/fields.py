"""Checked reads of a scenario object's fields (the shared JSON format): each helper returns the
field's value or raises ``ScenarioError`` naming the file and the field, with what it should be.

Bounds ``MAX_DT`` and ``MAX_ANGLE`` keep values that float32 arrays hold later within range.
"""

from __future__ import annotations

import math

import numpy as np


class ScenarioError(ValueError):
    """A scenario file that cannot be read; the message names the file and field."""


def _field(obj: dict, key: str, where: str, path: str, kind=None):
    if not isinstance(obj, dict) or key not in obj:
        raise ScenarioError(f"{path}: missing field {where}.{key}")
    val = obj[key]
    if kind is not None and not isinstance(val, kind):
        raise ScenarioError(
            f"{path}: field {where}.{key} should be {getattr(kind, '__name__', kind)}, got {type(val).__name__}"
        )
    return val


def _points(val, where: str, path: str, min_len: int = 1) -> np.ndarray:
    try:
        a = np.asarray(val, dtype=np.float64)
    except (TypeError, ValueError):
        raise ScenarioError(f"{path}: field {where} is not a list of [x, y] points") from None
    if a.ndim != 2 or a.shape[1] != 2 or len(a) < min_len:
        raise ScenarioError(f"{path}: field {where} should be >= {min_len} [x, y] points, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ScenarioError(f"{path}: field {where} contains NaN or inf")
    return a


def _number(obj, key, where, path) -> float:
    v = _field(obj, key, where, path)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ScenarioError(f"{path}: field {where}.{key} should be a finite number, got {v!r}")
    return float(v)


# Bounds on fields that float32 arrays hold later (beyond them a scene would hold inf, or nonsense).
MAX_DT = 10.0  # s: the time step
MAX_ANGLE = 1e4  # rad: headings (unwrapped recordings turn a few times at most)


def _angle(obj, key, where, path) -> float:
    v = _number(obj, key, where, path)
    if abs(v) > MAX_ANGLE:
        raise ScenarioError(f"{path}: field {where}.{key} should be an angle within +-{MAX_ANGLE:g} rad, got {v!r}")
    return v


def _int(obj, key, where, path) -> int:
    v = _field(obj, key, where, path)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v != int(v):
        raise ScenarioError(f"{path}: field {where}.{key} should be an integer, got {v!r}")
    return int(v)


def _ids(obj, key, where, path) -> tuple:
    """An optional list of integer ids (missing or null means none)."""
    v = obj.get(key) if isinstance(obj, dict) else None
    if v is None:
        return ()
    if not isinstance(v, list):
        raise ScenarioError(f"{path}: field {where}.{key} should be a list of ids")
    return tuple(_int({key: x}, key, where, path) for x in v)
