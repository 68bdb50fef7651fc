"""The run record: one sonar run (blocks, odometry, tracked poses) held in memory.

Its file format (``.npz``, :func:`mapping.files.write_run` / :func:`mapping.files.read_run`)
lives in :mod:`mapping.files`; this module knows no files.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.signal import SonarConfig


@dataclass(frozen=True)
class Run:
    """A tracked (or untracked) sonar run held in memory; see the module docstring."""

    config: SonarConfig
    samples: NDArray[np.float32]
    t_s: NDArray[np.float64]
    speed_m_s: NDArray[np.float64]
    yaw_rate_rad_s: NDArray[np.float64]
    pose: NDArray[np.float64]
    scene: str | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        validate_run(self)

    @property
    def n_blocks(self) -> int:
        """Number of blocks in the run."""
        return int(self.samples.shape[0])

    def block(self, k: int) -> NDArray[np.float32]:
        """Samples of block ``k``."""
        if not 0 <= k < self.n_blocks:
            raise ValueError(f"block index must be in 0..{self.n_blocks - 1}, got {k}")
        return self.samples[k]

    def neighbourhood(self, k: int, margin: int) -> tuple[NDArray[np.float64], int, int]:
        """Block ``k`` with up to ``margin`` samples of its neighbours on each side.

        Returns ``(samples, left, right)``: the extended samples and how many samples were
        taken from the previous and the next block (fewer at the ends of the run).
        """
        blk = self.block(k).astype(np.float64)
        left = min(margin, self.samples.shape[1]) if k > 0 else 0
        right = min(margin, self.samples.shape[1]) if k < self.n_blocks - 1 else 0
        parts = []
        if left:
            parts.append(self.samples[k - 1, -left:].astype(np.float64))
        parts.append(blk)
        if right:
            parts.append(self.samples[k + 1, :right].astype(np.float64))
        return np.concatenate(parts), left, right


def validate_run(run: Run) -> None:
    """Raise ``ValueError`` naming the first inconsistent field of ``run``."""
    b = run.config.block_samples
    s = run.samples
    if s.ndim != 2 or s.shape[1] != b:
        raise ValueError(f"run.samples must have shape (n_blocks, {b}), got {s.shape}")
    if s.dtype != np.float32:
        raise ValueError(f"run.samples must be float32, got {s.dtype}")
    if not np.all(np.isfinite(s)):
        raise ValueError("run.samples contains NaN or inf")
    n = s.shape[0]
    for name in ("t_s", "speed_m_s", "yaw_rate_rad_s"):
        arr = getattr(run, name)
        if arr.shape != (n,):
            raise ValueError(f"run.{name} must have shape ({n},), got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"run.{name} contains NaN or inf")
    if run.pose.shape != (n, 3):
        raise ValueError(f"run.pose must have shape ({n}, 3), got {run.pose.shape}")
    partial = np.isnan(run.pose).any(axis=1) & ~np.isnan(run.pose).all(axis=1)
    if partial.any():
        raise ValueError(
            f"run.pose rows must be all finite or all NaN; row {int(np.argmax(partial))} is mixed"
        )
    if np.isinf(run.pose).any():
        raise ValueError("run.pose contains inf")
