"""Strict JSON for everything the command line and the demo print (RFC 8259: no NaN).

A metric that does not exist (an RMSE after convergence when the filter never converged) is
NaN in the core; on the wire it is ``null``, never the invalid token ``NaN``.
"""

from __future__ import annotations

import json
from typing import Any

from mapping.files import json_safe


def strict_json(value: Any, indent: int | None = None) -> str:
    """Strict JSON of ``value`` (RFC 8259: no NaN or Infinity): non-finite floats become null
    (:func:`mapping.files.json_safe`) and ``allow_nan=False`` raises if one ever slips through."""
    return json.dumps(json_safe(value), indent=indent, allow_nan=False)
