"""Echo peaks of a heat map and of a run: the observations the wall fit explains.

A specular echo is a compact bump in the heat map: a chip-triangle wide in range (a few
4.25 mm bins) and a Doppler beam wide in direction. Peaks are the local maxima of ``H`` over a
window of ``range_window`` bins by ``angle_window`` rows that stand above the block's noise
floor (``snr`` times the robust noise level, the median of ``H``) and above ``min_relative``
of the block's strongest echo; each is refined to sub-bin precision by parabolas.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mapping.heatmap import HeatMap, heatmap_of_run
from mapping.run import Run
from mapping.walls._kernels import _local_maxima

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def check_fields(record: object, checks: tuple[tuple[str, bool], ...]) -> None:
    """``ValueError`` naming the first field of a parameter record whose check failed."""
    for name, ok in checks:
        if not ok:
            raise ValueError(f"{type(record).__name__}.{name} out of range: "
                             f"{getattr(record, name)!r}")


@dataclass(frozen=True)
class PeakParams:
    """How echoes are read off a heat map.

    Parameters
    ----------
    range_window : int
        Half-width in range bins of the local-maximum window (one chip is fs/chip_rate bins).
    angle_window : int
        Half-width in rows of the local-maximum window.
    snr : float
        A peak must exceed ``snr`` times the block's median (the noise and sidelobe floor).
    min_relative : float
        ... and ``min_relative`` times the block's maximum.
    min_range_m : float
        Echoes closer than this are ignored (the robot's own body, the direct-wave residue).
    max_range_m : float
        Echoes farther than this are ignored (weak, and multi-bounce paths dominate).
    max_peaks : int
        At most this many peaks per block (strongest first).
    min_speed_m_s : float
        Blocks slower than this are not used: the Doppler beam of eq. 1 is about
        ``4 c / (B v)`` wide in cos(theta) (one carrier cycle of drift over the block), so at
        0.05 m/s it spans 0.33 and the direction of an echo is barely told; a robot standing
        still (speed only odometry noise) would put every wall square to its heading.
    """

    range_window: int = 12
    angle_window: int = 2
    snr: float = 6.0
    min_relative: float = 0.08
    min_range_m: float = 0.15
    max_range_m: float = 6.0
    max_peaks: int = 24
    min_speed_m_s: float = 0.05

    def __post_init__(self) -> None:
        checks = (
            ("range_window", 1 <= self.range_window <= 200),
            ("angle_window", 0 <= self.angle_window <= 20),
            ("snr", math.isfinite(self.snr) and self.snr >= 0),
            ("min_relative", 0 <= self.min_relative < 1),
            ("min_range_m", math.isfinite(self.min_range_m) and self.min_range_m >= 0),
            ("max_range_m", math.isfinite(self.max_range_m)
             and self.max_range_m > self.min_range_m),
            ("max_peaks", 1 <= self.max_peaks <= 1000),
            ("min_speed_m_s", math.isfinite(self.min_speed_m_s) and self.min_speed_m_s >= 0),
        )
        check_fields(self, checks)


@dataclass(frozen=True)
class Peaks:
    """Echo peaks of one heat map (arrays of equal length, strongest first)."""

    range_m: FloatArray
    angle_rad: FloatArray
    value: FloatArray
    noise: float


def _parabola(ym: FloatArray, y0: FloatArray, yp: FloatArray) -> FloatArray:
    den = ym - 2.0 * y0 + yp
    safe = np.where(den < 0, den, -1.0)
    return np.where(den < 0, np.clip(0.5 * (ym - yp) / safe, -0.5, 0.5), 0.0)


def heatmap_peaks(hm: HeatMap, params: PeakParams = PeakParams()) -> Peaks:
    """Local maxima of ``hm.H`` that stand above its floor (see the module docstring)."""
    H = np.asarray(hm.H, dtype=np.float64)
    noise = float(np.median(H))
    thr = max(params.snr * noise, params.min_relative * float(H.max()))
    # the cells above thr that are the largest of their window (numba; the numpy twin with
    # scipy.ndimage.maximum_filter is in the tests)
    it, ir = _local_maxima(np.ascontiguousarray(H), thr, params.angle_window,
                           params.range_window)
    step = float(hm.ranges_m[1] - hm.ranges_m[0])
    r = ir * step
    keep = (r >= params.min_range_m) & (r <= params.max_range_m)
    it, ir = it[keep], ir[keep]
    order = np.argsort(-H[it, ir], kind="stable")[: params.max_peaks]
    it, ir = it[order], ir[order]
    p = H.shape[1]
    d_tau = _parabola(H[it, (ir - 1) % p], H[it, ir], H[it, (ir + 1) % p])
    last = H.shape[0] - 1
    below = H[np.where(it > 0, it - 1, 1), ir]
    above = H[np.where(it < last, it + 1, last - 1), ir]
    d_theta = _parabola(below, H[it, ir], above) if hm.direction_observable else 0.0 * d_tau
    idx = np.arange(H.shape[0], dtype=np.float64)
    angle = np.interp(it + d_theta, idx, hm.angles_rad)
    return Peaks(range_m=(ir + d_tau) * step, angle_rad=np.asarray(angle, dtype=np.float64),
                 value=H[it, ir], noise=noise)


@dataclass(frozen=True)
class PeakObservations:
    """Echo peaks of many blocks with the pose each was heard from (one row per peak).

    ``travel_rad`` is the direction of travel (the heading, or heading + pi when reversing):
    the angle of a peak is measured from it, folded left/right.
    """

    run: IntArray
    block: IntArray
    x_m: FloatArray
    y_m: FloatArray
    travel_rad: FloatArray
    range_m: FloatArray
    angle_rad: FloatArray
    value: FloatArray
    noise: FloatArray

    @property
    def size(self) -> int:
        """Number of peaks."""
        return int(self.range_m.size)

    def subset(self, mask: NDArray[np.bool_]) -> PeakObservations:
        """The rows where ``mask`` is True."""
        return PeakObservations(*(getattr(self, f)[mask] for f in _FIELDS))


_FIELDS = ("run", "block", "x_m", "y_m", "travel_rad", "range_m", "angle_rad", "value", "noise")


def run_peaks(run: Run, run_index: int = 0, params: PeakParams = PeakParams(),
              blocks: list[int] | None = None) -> PeakObservations:
    """Peaks of every tracked block of ``run`` whose direction is observable and whose speed
    reaches ``params.min_speed_m_s``."""
    rows: dict[str, list[FloatArray]] = {f: [] for f in _FIELDS}
    tracked = np.asarray(np.isfinite(run.pose).all(axis=1), dtype=bool)
    for k in (range(run.n_blocks) if blocks is None else blocks):
        if not bool(tracked[k]) or abs(run.speed_m_s[k]) < params.min_speed_m_s:
            continue
        hm = heatmap_of_run(run, k)
        if not hm.direction_observable:
            continue
        pk = heatmap_peaks(hm, params)
        n = pk.range_m.size
        x, y, heading = run.pose[k]
        travel = heading + (math.pi if run.speed_m_s[k] < 0 else 0.0)
        for f, v in (("run", run_index), ("block", k), ("x_m", x), ("y_m", y),
                     ("travel_rad", travel), ("noise", pk.noise)):
            rows[f].append(np.full(n, v))
        rows["range_m"].append(pk.range_m)
        rows["angle_rad"].append(pk.angle_rad)
        rows["value"].append(pk.value)
    cat = {f: (np.concatenate(v) if v else np.zeros(0)) for f, v in rows.items()}
    return PeakObservations(
        run=cat["run"].astype(np.int64), block=cat["block"].astype(np.int64),
        **{f: cat[f].astype(np.float64) for f in _FIELDS[2:]})


def concat_peaks(parts: list[PeakObservations]) -> PeakObservations:
    """Rows of all ``parts`` in order."""
    return PeakObservations(*(np.concatenate([getattr(p, f) for p in parts]) for f in _FIELDS))
