"""A heat map (or raw block) checked and prepared for scoring (:func:`prepare_measurement`);
see :mod:`localization.sensor`."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization.sensor._config import Model, SensorConfig
from localization.sensor._kernels import _EchoPeaks
from mapping.heatmap import HeatMap
from mapping.run import Run
from mapping.walls import PeakParams, Peaks, heatmap_peaks

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Measurement:
    """A heat map prepared for scoring.

    Attributes
    ----------
    model : {"correlation", "range", "echo"}
        The model actually used for this block.
    direction_observable : bool
        Whether the block carried direction information.
    dense : ndarray, shape (n_r * n_angles,) or (n_r,)
        Correlation model: the unfolded polar measurement above its noise floor
        (range-major). Range model: the zero-mean, unit-norm range profile.
    idx, val : ndarray
        Non-zero entries of ``dense`` (correlation model).
    m_mean, m_norm : float
        Mean of ``dense`` and norm of ``dense - m_mean`` (correlation model).
    peaks : optional
        Echo model: the block's heat-map peaks (range, Doppler cosine, weight) and the
        kernel widths; None for the G models.
    speed_m_s : float
        The block's odometry speed (the echo model predicts the Doppler with it).
    """

    model: Model
    direction_observable: bool
    dense: FloatArray
    idx: NDArray[np.int64]
    val: FloatArray
    m_mean: float
    m_norm: float
    peaks: _EchoPeaks | None = None
    speed_m_s: float = 0.0

    @property
    def n_peaks(self) -> int:
        """Echo peaks read off the block (echo model; 0 otherwise)."""
        return 0 if self.peaks is None else int(self.peaks.r.shape[0])


def heatmap_run(run: Run, config: SensorConfig) -> Run:
    """``run`` as the sensor model ``config`` hears it: its heat maps
    (:func:`mapping.heatmap.heatmap_of_run`) are made with
    :meth:`SensorConfig.heatmap_sonar` (the echo model's denser bank); the run itself
    when that is its own sonar."""
    sonar = config.heatmap_sonar(run.config)
    return run if sonar == run.config else dataclasses.replace(run, config=sonar)


def validate_heatmap(heat_map: HeatMap) -> None:
    """Raise ``ValueError`` if ``heat_map`` cannot be scored (NaN, zeros, bad axes)."""
    H = np.asarray(heat_map.H)
    if H.ndim != 2 or H.shape[0] < 2 or H.shape[1] < 2:
        raise ValueError(f"heat_map.H must be 2-D with >= 2 rows and columns, got {H.shape}")
    if heat_map.angles_rad.shape != (H.shape[0],) or heat_map.ranges_m.shape != (H.shape[1],):
        raise ValueError(
            f"heat_map axes must have shapes ({H.shape[0]},) and ({H.shape[1]},), got "
            f"{heat_map.angles_rad.shape} and {heat_map.ranges_m.shape}"
        )
    if not np.all(np.isfinite(H)):
        raise ValueError("heat_map.H contains NaN or inf")
    if not np.any(H != 0):
        raise ValueError("heat_map.H is all zeros (a dropout block); pass None to predict only")
    a = heat_map.angles_rad
    if not (np.all(np.isfinite(a)) and a.min() >= -1e-9 and a.max() <= np.pi + 1e-9
            and np.all(np.diff(a) > 0)):
        raise ValueError("heat_map.angles_rad must increase within [0, pi]")
    if not (np.all(np.diff(heat_map.ranges_m) > 0) and math.isfinite(heat_map.speed_m_s)):
        raise ValueError("heat_map.ranges_m must increase and heat_map.speed_m_s be finite")


def validate_block(samples: NDArray[np.floating], block_samples: int,
                   clip_fraction: float = 1e-3) -> None:
    """Raise ``ValueError`` for a raw sonar block that must not reach the filter.

    Rejects a wrong length, NaN/inf, an all-zero block (dropout) and a clipped block (more
    than ``clip_fraction`` of the samples, and at least 8, sitting at the peak magnitude).
    """
    x = np.asarray(samples)
    if x.ndim != 1 or x.shape[0] != block_samples:
        raise ValueError(f"block must have shape ({block_samples},), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("block contains NaN or inf")
    peak = float(np.max(np.abs(x)))
    if peak == 0.0:
        raise ValueError("block is all zeros (dropout)")
    at_peak = int(np.count_nonzero(np.abs(x) >= peak * (1 - 1e-6)))
    if at_peak >= max(8, clip_fraction * x.shape[0]):
        raise ValueError(
            f"block is clipped: {at_peak} samples sit at the peak magnitude {peak:g} "
            f"(allowed < {max(8, int(clip_fraction * x.shape[0]))})"
        )


def uses_direction(heat_map: HeatMap, config: SensorConfig) -> bool:
    """Whether this block may inform the heading (observable and fast enough)."""
    return bool(heat_map.direction_observable) and abs(heat_map.speed_m_s) >= config.min_speed_m_s


def prepare_measurement(heat_map: HeatMap, config: SensorConfig) -> Measurement:
    """Bin, unfold and normalize a heat map for scoring; see the module docstring.

    The heat map's columns are averaged into the range bins and multiplied by
    ``r ** range_gain_exponent``. Correlation model: rows interpolated at ``|phi_j|`` (the
    mirror fold; ``pi - |phi_j|`` when reversing, since the heat map's angles are measured
    from the direction of travel) and the noise floor (the ``1 - keep_fraction`` quantile)
    removed. Range model: the maximum over directions, zero mean and unit norm.

    Raises
    ------
    ValueError
        Bad heat map (see :func:`validate_heatmap`) or no structure within the range bins.
    """
    validate_heatmap(heat_map)
    directional = uses_direction(heat_map, config)
    if config.model == "echo":
        return _echo_measurement(heat_map, config, directional)
    model: Model = config.model if directional else "range"
    binned = _bin_ranges(np.asarray(heat_map.H, dtype=np.float64), heat_map.ranges_m, config)
    binned *= config.ranges_m[None, :] ** config.range_gain_exponent
    empty = np.zeros(0)
    if model == "range":
        m = binned.max(axis=0)
        m = m - m.mean()
        norm = float(np.linalg.norm(m))
        if norm == 0.0:
            raise ValueError("heat_map has no structure within the sensor's range bins")
        return Measurement(model=model, direction_observable=directional, dense=m / norm,
                           idx=empty.astype(np.int64), val=empty, m_mean=0.0, m_norm=1.0)
    phi = np.abs(config.angles_rad)
    if heat_map.speed_m_s < 0:
        # reversing: the heat map's angles are measured from the direction of travel,
        # heading + pi (mapping.heatmap.doppler_heatmap)
        phi = np.pi - phi
    lo = np.clip(np.searchsorted(heat_map.angles_rad, phi) - 1, 0, binned.shape[0] - 2)
    a0, a1 = heat_map.angles_rad[lo], heat_map.angles_rad[lo + 1]
    t = np.clip((phi - a0) / (a1 - a0), 0.0, 1.0)
    rows = binned[lo] * (1 - t)[:, None] + binned[lo + 1] * t[:, None]   # (n_angles, n_r)
    m = rows.T.ravel()
    m = np.maximum(m - np.quantile(m, 1.0 - config.keep_fraction), 0.0)
    m_mean = float(m.mean())
    m_norm = float(np.linalg.norm(m - m_mean))
    if m_norm == 0.0:
        raise ValueError("heat_map has no structure within the sensor's range bins")
    idx = np.flatnonzero(m)
    return Measurement(model=model, direction_observable=directional, dense=m,
                       idx=idx.astype(np.int64), val=m[idx], m_mean=m_mean, m_norm=m_norm)


def _bin_ranges(H: FloatArray, ranges_m: FloatArray, config: SensorConfig) -> FloatArray:
    """Mean of the columns of ``H`` in each range bin (n_dirs, n_r)."""
    edges = np.append(config.ranges_m - 0.5 * config.range_step_m,
                      config.ranges_m[-1] + 0.5 * config.range_step_m)
    idx = np.searchsorted(ranges_m, edges)
    # prefix sums only up to the last bin edge (the sensor's max range is a fraction of
    # the heat map's columns); the sums are sequential, so the values are the same
    hi = int(idx[-1])
    csum = np.concatenate([np.zeros((H.shape[0], 1)), np.cumsum(H[:, :hi], axis=1)], axis=1)
    counts = np.diff(idx)
    sums = csum[:, idx[1:]] - csum[:, idx[:-1]]
    return np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)


def _log_levels(value: FloatArray) -> FloatArray:
    """Natural log of each peak's heat-map value relative to the strongest (0 for a value
    that is not positive)."""
    v = np.asarray(value, dtype=np.float64)
    top = float(v.max(initial=0.0))
    if top <= 0.0:
        return np.zeros_like(v)
    return np.ascontiguousarray(np.log(np.maximum(v, 1e-12 * top) / top))


#: Half-width (rad) of the echo model's local-maximum window across directions: the
#: default :class:`mapping.walls.PeakParams` window (2 rows) on the paper's 29-direction bank.
PEAK_ANGLE_WINDOW_RAD = 2.0 * math.pi / 29


def peak_angle_window(heat_map: HeatMap) -> int:
    """Half-width in rows of the echo model's peak window on ``heat_map``'s bank: the same
    angle, ``PEAK_ANGLE_WINDOW_RAD``, whatever the bank's density (2 rows on 29 directions,
    4 on the echo model's 58), so a denser bank finds the same peaks, not their sidelobes."""
    a = np.asarray(heat_map.angles_rad, dtype=np.float64)
    step = float(a[-1] - a[0]) / max(a.size - 1, 1)
    return max(1, round(PEAK_ANGLE_WINDOW_RAD / step)) if step > 0 else 1


def _echo_measurement(heat_map: HeatMap, config: SensorConfig, directional: bool) -> Measurement:
    """The echo model's measurement: the block's strongest heat-map peaks
    (:func:`mapping.walls.heatmap_peaks`), each with unit weight, and the kernel widths.

    Angles are measured from the direction of travel (heading + pi when reversing), as the
    forward model's Doppler cosines are, so no flip is needed here. A block without peaks
    is valid (it informs through the echoes it does not contain) but carries no evidence
    of where the robot is; the filter reports it (``n_peaks``). The Doppler-cosine width
    depends on the sonar (carrier, block length), which the scorer knows: ``sig_c`` here
    is only the floor ``cos_sigma_min``.
    """
    n_rows = int(np.asarray(heat_map.H).shape[0])
    rows = 1 if directional else n_rows
    params = PeakParams(snr=config.peak_snr, min_relative=0.08, min_range_m=config.min_range_m,
                        max_range_m=config.max_range_m, max_peaks=config.peaks_read * rows,
                        min_speed_m_s=0.0, angle_window=peak_angle_window(heat_map))
    # only the lags up to the sensor's range (plus the peak window) can hold a peak it reads
    cols = min(int(np.searchsorted(heat_map.ranges_m, config.max_range_m)) + 2 * 12 + 1,
               heat_map.H.shape[1])
    cropped = HeatMap(H=np.asarray(heat_map.H)[:, :cols], angles_rad=heat_map.angles_rad,
                      ranges_m=heat_map.ranges_m[:cols], speed_m_s=heat_map.speed_m_s,
                      direction_observable=heat_map.direction_observable)
    pk = heatmap_peaks(cropped, params)
    if not directional:
        # every row of eq. 1 is the same without direction information: one peak per range
        _, first = np.unique(np.round(pk.range_m, 6), return_index=True)
        keep = np.sort(first)[: config.peaks_read]       # strongest first, as heatmap_peaks
        pk = Peaks(range_m=pk.range_m[keep], angle_rad=pk.angle_rad[keep],
                   value=pk.value[keep], noise=pk.noise)
    peaks = _EchoPeaks(r=np.ascontiguousarray(pk.range_m, dtype=np.float64),
                       c=np.ascontiguousarray(np.cos(pk.angle_rad), dtype=np.float64),
                       w=np.ones(pk.range_m.shape[0]), la=_log_levels(pk.value),
                       sig_r=float(config.range_sigma_m),
                       sig_c=float(config.cos_sigma_min),   # widened by the scorer

                       use_cos=bool(directional))
    empty = np.zeros(0)
    return Measurement(model="echo", direction_observable=directional, dense=empty,
                       idx=empty.astype(np.int64), val=empty, m_mean=0.0, m_norm=1.0,
                       peaks=peaks, speed_m_s=float(heat_map.speed_m_s))
