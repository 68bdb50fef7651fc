"""Log-weight bookkeeping and resampling for the particle filter.

Weights live as float64 log-weights normalized with log-sum-exp, so a sharp likelihood over
10^5 particles never underflows to all-zero weights. Resampling is systematic (one uniform
draw, n evenly spaced pointers; Kitagawa 1996): unbiased (particle ``i`` is copied
``n w_i`` times in expectation, ``floor`` or ``ceil`` of it exactly) and with the lowest
variance of the common schemes. filterpy's residual resampler (its issue 290) is the
cautionary tale for getting the counts wrong; the tests check them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from localization import _kernels as _k

FloatArray = NDArray[np.float64]


def log_sum_exp(log_w: FloatArray) -> float:
    """``log(sum(exp(log_w)))`` of a 1-D array, shifted by its maximum so nothing overflows
    (-inf when every entry is -inf; +inf or NaN in, the same out). The filter calls it a few
    times per block on every particle: scipy's ``logsumexp`` gives the same value (to
    round-off) at several times the cost of its argument checks on 2000 entries."""
    a = np.asarray(log_w, dtype=np.float64)
    m = float(np.max(a))
    if not np.isfinite(m):
        return m
    return m + float(np.log(np.sum(np.exp(a - m))))


def normalize_log_weights(log_w: FloatArray) -> tuple[FloatArray, float]:
    """Subtract log-sum-exp: returns ``(log_w - lse, lse)`` so ``sum(exp(result)) == 1``.

    Raises
    ------
    ValueError
        If ``log_w`` is empty, contains NaN or +inf, or is all -inf.
    """
    log_w = np.asarray(log_w, dtype=np.float64)
    if log_w.ndim != 1 or log_w.size == 0:
        raise ValueError(f"log_w must be a non-empty 1-D array, got shape {log_w.shape}")
    if np.isnan(log_w).any() or np.isposinf(log_w).any():
        raise ValueError("log_w contains NaN or +inf")
    lse = log_sum_exp(log_w)
    if not np.isfinite(lse):
        raise ValueError("log_w is all -inf: every particle has zero weight")
    return log_w - lse, lse


def effective_sample_size(log_w: FloatArray) -> float:
    """ESS ``1 / sum(w_i^2)`` of normalized log-weights, in [1, n]."""
    w = np.exp(np.asarray(log_w, dtype=np.float64))
    return float(1.0 / np.sum(w * w))


def systematic_resample(
    weights: FloatArray, rng: np.random.Generator, n_out: int | None = None
) -> NDArray[np.int64]:
    """Indices of ``n_out`` particles drawn by systematic resampling.

    Parameters
    ----------
    weights : ndarray, shape (n,)
        Non-negative weights; renormalized here.
    rng : numpy.random.Generator
        One uniform draw is taken.
    n_out : int, optional
        Number of particles to draw (default n).

    Returns
    -------
    ndarray of int64, shape (n_out,)
        Sorted indices into ``weights``.
    """
    w = _checked_weights(weights)
    n_out = w.shape[0] if n_out is None else int(n_out)
    if n_out < 1:
        raise ValueError(f"n_out must be >= 1, got {n_out}")
    return _k.systematic(w, float(rng.random()), n_out)


def systematic_resample_u0(weights: FloatArray, u0: float, n_out: int) -> NDArray[np.int64]:
    """:func:`systematic_resample` with a given draw ``u0`` in [0, 1) instead of a generator.

    Deterministic: the tests compare it with the kernel's numpy twin
    (``tests/localization/naive.py``) and check its counts.
    """
    if not 0.0 <= u0 < 1.0:
        raise ValueError(f"u0 must be in [0, 1), got {u0}")
    return _k.systematic(_checked_weights(weights), u0, n_out)


def _checked_weights(weights: FloatArray) -> FloatArray:
    w = np.ascontiguousarray(weights, dtype=np.float64)
    if w.ndim != 1 or w.size == 0:
        raise ValueError(f"weights must be a non-empty 1-D array, got shape {w.shape}")
    if not np.all(np.isfinite(w)) or (w < 0).any():
        raise ValueError("weights must be finite and >= 0")
    total = w.sum()
    if total <= 0:
        raise ValueError("weights sum to zero")
    return w / total
