"""Wall-level precision and recall of fitted walls against the true walls."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.files import json_safe
from mapping.quality._geometry import (
    _check_segments,
    _line_angle_deg,
    _segment_distances,
    distance_to_walls,
    wall_sample_index,
    wall_samples,
)

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class WallMatch:
    """A found true wall and the fitted wall that covers most of its observed part."""

    true_index: int
    fitted_index: int
    covered_share: float
    angle_error_deg: float
    endpoint_error_m: tuple[float | None, float | None]


@dataclass(frozen=True)
class WallQuality:
    """Wall-level precision and recall (see the module docstring for the definitions).

    Index tuples refer to the true segments (``found``, ``missed``, ``unobserved``) or to the
    fitted walls (``false_walls``, ``ambiguous``).
    """

    tol_m: float
    share: float
    n_true: int
    n_true_observed: int
    n_fitted: int
    n_found: int
    n_false: int
    n_ambiguous: int
    precision: float
    recall: float
    found: tuple[int, ...]
    missed: tuple[int, ...]
    unobserved: tuple[int, ...]
    false_walls: tuple[int, ...]
    ambiguous: tuple[int, ...]
    matches: tuple[WallMatch, ...]
    angle_error_deg_max: float
    endpoint_error_m_max: float

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dictionary (NaN as null)."""
        return json_safe(asdict(self))



def _check_fitted(walls_m: FloatArray) -> FloatArray:
    w = np.asarray(walls_m, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != 4 or not np.all(np.isfinite(w)):
        raise ValueError(f"walls_m must be a finite (n, 4) array, got shape {w.shape}")
    return w.reshape(-1, 2, 2)


def _match(i: int, obs_i: BoolArray, d_obs: FloatArray, ends_seen: tuple[bool, bool],
           true_seg: FloatArray, fitted: FloatArray, tol_m: float) -> WallMatch:
    """The fitted wall covering most observed samples of true wall i, and its errors."""
    within = d_obs[obs_i] <= tol_m  # (k, n)
    j = int(np.argmax(within.sum(axis=0)))
    angle = _line_angle_deg(true_seg[1] - true_seg[0], fitted[j][1] - fitted[j][0])
    ends: list[float | None] = []
    for end, seen in zip(true_seg, ends_seen, strict=True):
        ends.append(float(np.min(np.hypot(*(fitted[j] - end).T))) if seen else None)
    covered = float(np.mean(within.any(axis=1)))
    return WallMatch(i, j, covered, angle, (ends[0], ends[1]))


def evaluate_walls(walls_m: FloatArray, true_segments: FloatArray,
                   observed: BoolArray | None = None, tol_m: float = 0.10, share: float = 0.8,
                   *, pair: NDArray[np.int64] | None = None,
                   spacing_m: float = 0.01) -> WallQuality:
    """Wall-level precision and recall of fitted walls against the true walls.

    Parameters
    ----------
    walls_m : ndarray, shape (n, 4)
        Fitted walls ``x0, y0, x1, y1`` in metres (``WallMap.walls_m``); n may be 0.
    true_segments : ndarray, shape (W, 2, 2)
        True walls (``Scene.segments()``), metres.
    observed : ndarray of bool, optional
        One entry per point of ``wall_samples(true_segments, spacing_m)``: the part of the
        true walls the runs could observe (:func:`observed_wall_mask`,
        :func:`observed_near_points`). Default: all of it.
    tol_m : float
        Distance within which a sample counts as on a wall (10 cm).
    share : float
        Share of a wall that must be within ``tol_m`` (0.8).
    pair : ndarray of int, shape (n,), optional
        Mirror hypothesis of each fitted wall or -1 (``WallMap.wall_pair``).
    spacing_m : float
        Sample spacing along the walls (1 cm).

    Returns
    -------
    WallQuality

    Raises
    ------
    ValueError
        Naming the argument of the wrong shape or value.
    """
    if not (tol_m > 0 and 0 < share <= 1):
        raise ValueError(f"tol_m must be > 0 and share in (0, 1], got {tol_m}, {share}")
    seg = _check_segments(true_segments)
    fitted = _check_fitted(walls_m)
    n = fitted.shape[0]
    pairs = np.full(n, -1, np.int64) if pair is None else np.asarray(pair, dtype=np.int64)
    if pairs.shape != (n,):
        raise ValueError(f"pair must have shape ({n},), got {pairs.shape}")
    samples, index = wall_samples(seg, spacing_m), wall_sample_index(seg, spacing_m)
    obs = np.ones(index.size, bool) if observed is None else np.asarray(observed, dtype=bool)
    if obs.shape != index.shape:
        raise ValueError(f"observed must have one entry per wall sample, shape {index.shape}, "
                         f"got {obs.shape}")
    d_obs = _segment_distances(samples, fitted) if n else np.zeros((index.size, 0))
    near_any = d_obs.min(axis=1) <= tol_m if n else np.zeros(index.size, bool)
    found, missed, unobserved, matches = [], [], [], []
    for i in range(seg.shape[0]):
        obs_i = obs & (index == i)
        if obs_i.sum() * spacing_m < tol_m:  # (almost) nothing of it observed
            unobserved.append(i)
            continue
        if np.mean(near_any[obs_i]) < share:
            missed.append(i)
            continue
        found.append(i)
        rows = np.flatnonzero(index == i)
        ends_seen = (bool(obs[rows[0]]), bool(obs[rows[-1]]))
        matches.append(_match(i, obs_i, d_obs, ends_seen, seg[i], fitted, tol_m))
    true_pos = np.zeros(n, bool)
    if n:
        fit_samples, fit_index = wall_samples(fitted, spacing_m), wall_sample_index(fitted,
                                                                                    spacing_m)
        on_true = distance_to_walls(fit_samples, seg) <= tol_m
        true_pos = np.bincount(fit_index, on_true, n) / np.bincount(fit_index, minlength=n) \
            >= share
    mirror = (~true_pos) & (pairs >= 0) & true_pos[np.maximum(pairs, 0)]
    false_walls = np.flatnonzero(~true_pos & ~mirror)
    n_obs = len(found) + len(missed)
    judged = n - int(mirror.sum())
    angles = [m.angle_error_deg for m in matches]
    ends = [e for m in matches for e in m.endpoint_error_m if e is not None]
    return WallQuality(
        tol_m=tol_m, share=share, n_true=seg.shape[0], n_true_observed=n_obs, n_fitted=n,
        n_found=len(found), n_false=int(false_walls.size), n_ambiguous=int(mirror.sum()),
        precision=float(true_pos.sum() / judged) if judged else math.nan,
        recall=len(found) / n_obs if n_obs else math.nan,
        found=tuple(found), missed=tuple(missed), unobserved=tuple(unobserved),
        false_walls=tuple(int(j) for j in false_walls),
        ambiguous=tuple(int(j) for j in np.flatnonzero(mirror)), matches=tuple(matches),
        angle_error_deg_max=max(angles) if angles else math.nan,
        endpoint_error_m_max=max(ends) if ends else math.nan,
    )


