"""Strict JSON for everything the command line and the demo print (RFC 8259: no NaN).

A metric that does not exist (an RMSE after convergence when the filter never converged) is
NaN in the core; on the wire it is ``null``, never the invalid token ``NaN``.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, +-inf) replaced by None, recursively
    through dicts, lists and tuples; numpy scalars and arrays become Python ones."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [json_safe(v) for v in (value.tolist() if isinstance(value, np.ndarray) else value)]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    return value


def strict_json(value: Any, indent: int | None = None) -> str:
    """Strict JSON of ``value`` (RFC 8259: no NaN or Infinity): non-finite floats become null
    (:func:`json_safe`) and ``allow_nan=False`` raises if one ever slips through."""
    return json.dumps(json_safe(value), indent=indent, allow_nan=False)
