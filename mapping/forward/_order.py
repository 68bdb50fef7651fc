"""How many reflection orders a scene needs: :func:`required_order`."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from mapping.forward._echoes import MAX_ORDER, ForwardParams, WallSet, echoes_batch
from mapping.signal import SonarConfig

#: Default level (relative to the strongest echo of the pose) below which omitted higher-order
#: paths are ignored: -20 dB, the level where an echo stops forming its own local maximum next
#: to the strongest one at 0.1 m/s (see the forward-model guide).
DEFAULT_LEVEL = 0.1


def required_order(
    walls: WallSet,
    poses: ArrayLike,
    speed_m_s: float,
    config: SonarConfig,
    *,
    level: float = DEFAULT_LEVEL,
    max_range_m: float | None = None,
    spreading: str = "3d",
    highest: int = MAX_ORDER,
) -> int:
    """Smallest order whose omitted paths are all weak: every path of a higher order (up to
    ``highest``) within ``max_range_m`` has ``|amplitude| < level * (strongest echo)`` at
    every pose.

    Parameters
    ----------
    walls : WallSet
    poses : array_like, shape (n, 3)
        Poses to check (e.g. a few along a run).
    speed_m_s : float
    config : SonarConfig
    level : float
        Relative amplitude threshold in (0, 1]; default 0.1 (-20 dB).
    max_range_m : float or None
        One-way range of interest (None: the unambiguous range).
    spreading : {"3d", "2d"}
    highest : int
        Highest order looked at (1..4); returned when even it omits strong paths.

    Returns
    -------
    int
        In 1..highest.
    """
    if not 0 < level <= 1:
        raise ValueError(f"level must be in (0, 1], got {level!r}")
    if not isinstance(highest, int) or not 1 <= highest <= MAX_ORDER:
        raise ValueError(f"highest must be an integer in 1..{MAX_ORDER}, got {highest!r}")
    params = ForwardParams(max_order=highest, spreading=spreading, max_range_m=max_range_m)
    batch = echoes_batch(walls, poses, speed_m_s, config, params)
    amp = np.abs(np.nan_to_num(batch.amplitude))
    if amp.size == 0:
        return 1
    strongest = amp.max(axis=1, keepdims=True)
    strong = amp >= level * strongest
    orders = np.where(strong & (amp > 0), batch.order, 0)
    return int(max(1, orders.max()))
