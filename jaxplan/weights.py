"""Weights files: the JSON that ``jaxplan tune`` writes and every planner's ``init_params`` (and
``jaxplan drive --weights``) reads, ``{"weights": {name: value}, "meta": {...}}``; ``HANDSET`` names
every planner's built-in weights instead of a file."""

from __future__ import annotations

import json
import os

import numpy as np

HANDSET = "handset"  # the name (not a file) of every planner's built-in, hand-set weights (``--weights``)


def save_weights(path: str, weights: dict, meta: dict | None = None) -> None:
    """Write positive weights (and optional metadata) as JSON, atomically."""
    d = {"weights": {k: float(v) for k, v in weights.items()}, **({"meta": meta} if meta else {})}
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path + ".tmp", "w") as f:
        json.dump(d, f, indent=1, sort_keys=True)
    os.replace(path + ".tmp", path)


def load_weights(path: str, allowed=None, planner: str | None = None) -> dict:
    """Read weights written by ``save_weights``; a clear ``ValueError`` names a bad file.

    Args:
        path: the JSON file, or ``HANDSET`` (``"handset"``): no file, ``{}``, so that every planner
            keeps its built-in (hand-set) weights (``init_params({})``), to compare with a tuned file.
        allowed: the weight names the caller's planner has (e.g.
            ``jaxplan.tuning.lattice_tuning.WEIGHT_NAMES``); any other key, a misspelling
            like ``alhpa`` included, is refused with the list of allowed names.
        planner: the planner the weights are for; a file whose ``meta.planner`` names another
            one is refused.

    Returns:
        ``{name: weight}``, every weight finite and positive.
    """
    if path == HANDSET:
        return {}
    try:
        with open(path) as f:
            d = json.load(f)
        if isinstance(d, dict) and str(d.get("kind", "")).startswith("jaxplan.imitation"):
            raise LookupError
        w = d["weights"]
        out = {str(k): float(v) for k, v in w.items()}
    except LookupError as e:
        if isinstance(e, KeyError):
            raise ValueError(f"{path}: not a weights file (KeyError: {e})") from None
        raise ValueError(
            f"{path}: an imitation cost over scene features (jaxplan.tuning.imitation.ImitationModel), "
            "not the lattice rule's weights (the `.rule.json` beside it holds those)"
        ) from None
    except (OSError, json.JSONDecodeError, TypeError, ValueError, AttributeError) as e:
        raise ValueError(f"{path}: not a weights file ({type(e).__name__}: {e})") from None
    meta = d.get("meta") if isinstance(d, dict) else None
    if planner is not None and isinstance(meta, dict) and meta.get("planner") not in (None, planner):
        raise ValueError(f"{path}: weights for the {meta.get('planner')!r} planner, not for {planner!r}")
    if allowed is not None:
        unknown = sorted(set(out) - set(allowed))
        if unknown:
            raise ValueError(
                f"{path}: unknown weight {unknown[0]!r}"
                f"{f' (and {len(unknown) - 1} more)' if len(unknown) > 1 else ''}; "
                f"allowed: {', '.join(allowed)}"
            )
    bad = [k for k, v in out.items() if not (np.isfinite(v) and v > 0)]
    if bad:
        raise ValueError(f"{path}: weights must be positive and finite, not {bad}")
    return out
