"""Reading the project's versioned ``.npz`` containers (run files, map files).

Each container holds a string key ``format`` naming its format and version; readers refuse
anything else with a ``ValueError`` naming the file and the problem.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np


def read_npz(path: str | os.PathLike[str], format_name: str | tuple[str, ...], kind: str,
             required: Iterable[str]) -> dict[str, Any]:
    """All arrays of the ``.npz`` at ``path`` after checking its ``format`` and keys.

    Parameters
    ----------
    path
        The file; ``FileNotFoundError`` propagates unchanged.
    format_name
        Required value of the ``format`` key, or the accepted values (versions a reader knows).
    kind
        Word for the error message ("run", "map").
    required
        Keys that must be present.

    Raises
    ------
    ValueError
        Unreadable file, wrong ``format`` or missing keys (message starts with the path).
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
    except FileNotFoundError:
        raise
    except Exception as exc:  # zipfile / numpy errors on truncated or foreign files
        raise ValueError(f"{path}: not a readable .npz {kind} file ({exc})") from exc
    fmt = str(data.get("format", ""))
    accepted = (format_name,) if isinstance(format_name, str) else format_name
    if fmt not in accepted:
        wanted = repr(accepted[0]) if len(accepted) == 1 else f"one of {list(accepted)}"
        raise ValueError(f"{path}: key 'format' must be {wanted}, got {fmt!r}")
    missing = [k for k in required if k not in data]
    if missing:
        raise ValueError(f"{path}: missing key(s) {missing}")
    return data
