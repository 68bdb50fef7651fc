"""Sensor model: the likelihood of a live heat map given a pose and the wall map G.

At a pose ``(x, y, heading)`` the map predicts what the sonar should see by sampling G on a
polar grid around the pose: ``n_angles`` directions ``phi_j = 2 pi j / n_angles`` measured
from the heading, over the full circle, and range bins ``r_k``. This inverts the paper's
back-projection (Sec. 2.2, eqs. 2-4: a heat-map pixel at direction ``n_theta`` and lag
``n_tau`` lands on the map cell at that bearing and range ``c n_tau / (2 fs)``).

The measured heat map (eq. 1) only knows ``|phi|`` in [0, pi]: the Doppler factor depends on
``cos(theta)``, so the left and right mirror directions are the same row. The measurement is
therefore *unfolded* onto the same full-circle grid, ``M[k, j] = H(|phi_j|, r_k)`` (mirror
sides equal), and compared with the prediction by the Pearson correlation ``rho`` over all
polar bins. Because ``M`` is mirror symmetric, this equals correlating the folded prediction
``P(+phi) + P(-phi)`` with ``H``.

Two models share the tables:

``correlation``  the full polar correlation above;
``range``        range-only: the measured range profile (max over directions) against the
                 prediction summed over all directions at each range. The sum (not a max)
                 is deliberate: a ring of radius r around the pose grazes a wall at its
                 perpendicular distance, where the ring runs along the wall, so the ring sum
                 peaks at the specular ranges the sonar actually hears. The range model does
                 not depend on the heading at all (the particle filter evaluates it at
                 heading bin 0), so a stationary robot never invents a bearing.

The correlation becomes a likelihood by tempering and flooring (AMCL's ``z_rand``)::

    p(z | x) = (1 - z_rand) exp(beta (rho - 1)) + z_rand

Lookup tables make one particle a gather and a dot product: G (lightly blurred, padded by
the maximum range) is flattened, the direction cosines of every (heading bin, polar angle)
and the ranges in cells are tabulated, and the sample sums the correlation's denominator
needs are precomputed per cell; a particle then costs one nearest-cell gather and one
multiply-add per kept measurement entry. (A table of precomputed flat offsets per heading
bin and sub-cell phase was tried first: 36 MB, and on this shared machine reading its rows
cost more than computing the offsets.) Exhaustive scoring of every heading at a cell
is a circular cross-correlation along the angle axis, done with FFTs
(:func:`score_cells_all_headings`); it is exactly the particle score at the cell centre and
heading ``2 pi m / n_angles``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from localization import _sensor_kernels as _k
from mapping.heatmap import HeatMap
from mapping.wallmap import WallMap

FloatArray = NDArray[np.float64]
Model = Literal["correlation", "range"]

#: Log-likelihood given to a pose outside the map (below the z_rand floor).
OFF_MAP_PENALTY = 10.0


@dataclass(frozen=True)
class SensorConfig:
    """Parameters of the sensor model.

    Parameters
    ----------
    model : {"correlation", "range"}
        Full polar correlation, or range-only. "correlation" still falls back to "range"
        for a block without direction information (see ``min_speed_m_s``).
    n_angles : int
        Directions of the full-circle polar grid (72 = 5 deg); also the grid filter's
        heading bins.
    range_step_m, min_range_m, max_range_m : float
        Range bins ``min_range_m + k * range_step_m`` below ``max_range_m``.
    n_headings : int
        Heading bins of the direction table (1 deg by default); a multiple of ``n_angles``.
    beta : float
        Sharpness: log-likelihood ``beta * (rho - 1)`` before the floor.
    z_rand : float
        Weight of the uniform floor in (0, 1).
    min_speed_m_s : float
        At ``|speed|`` below this the range-only model is used automatically.
    map_blur_cells : float
        Gaussian blur (standard deviation, cells) applied to G before sampling.
    range_gain_exponent : float
        The measured heat map is multiplied by ``r ** range_gain_exponent`` to undo the
        spreading loss before it is compared with G.
    keep_fraction : float
        Share of the unfolded measurement kept above the noise floor: the
        ``1 - keep_fraction`` quantile is subtracted and negatives set to 0, so the cross
        term of the correlation is a sparse dot product.
    """

    model: Model = "correlation"
    n_angles: int = 72
    range_step_m: float = 0.05
    min_range_m: float = 0.15
    max_range_m: float = 5.0
    n_headings: int = 360
    beta: float = 200.0
    z_rand: float = 0.001
    min_speed_m_s: float = 0.03
    map_blur_cells: float = 1.0
    range_gain_exponent: float = 1.0
    keep_fraction: float = 0.10

    def __post_init__(self) -> None:
        if self.model not in ("correlation", "range"):
            raise ValueError(f"model must be 'correlation' or 'range', got {self.model!r}")
        if not 8 <= self.n_angles <= 720 or self.n_angles % 2:
            raise ValueError(f"n_angles must be even in [8, 720], got {self.n_angles}")
        if self.n_headings < self.n_angles or self.n_headings % self.n_angles:
            raise ValueError(
                f"n_headings must be a multiple of n_angles={self.n_angles}, got "
                f"{self.n_headings}"
            )
        if not 0 < self.range_step_m <= 1.0:
            raise ValueError(f"range_step_m must be in (0, 1] m, got {self.range_step_m}")
        if not 0 <= self.min_range_m < self.max_range_m - self.range_step_m:
            raise ValueError(
                "need 0 <= min_range_m < max_range_m - range_step_m, got "
                f"{self.min_range_m}, {self.max_range_m}"
            )
        if not (math.isfinite(self.beta) and self.beta > 0):
            raise ValueError(f"beta must be > 0, got {self.beta}")
        if not 0 < self.z_rand < 1:
            raise ValueError(f"z_rand must be in (0, 1), got {self.z_rand}")
        if not self.min_speed_m_s >= 0:
            raise ValueError(f"min_speed_m_s must be >= 0, got {self.min_speed_m_s}")
        if not 0 < self.keep_fraction <= 1:
            raise ValueError(f"keep_fraction must be in (0, 1], got {self.keep_fraction}")
        if not self.map_blur_cells >= 0:
            raise ValueError(f"map_blur_cells must be >= 0, got {self.map_blur_cells}")

    @property
    def ranges_m(self) -> FloatArray:
        """Centres of the range bins, shape (n_r,)."""
        n_r = int(math.floor((self.max_range_m - self.min_range_m) / self.range_step_m))
        return np.asarray(self.min_range_m + self.range_step_m * np.arange(n_r),
                          dtype=np.float64)

    @property
    def angles_rad(self) -> FloatArray:
        """Polar directions relative to the heading, wrapped to (-pi, pi], shape (n_angles,)."""
        a = 2.0 * np.pi * np.arange(self.n_angles) / self.n_angles
        return np.where(a > np.pi, a - 2.0 * np.pi, a)


@dataclass(frozen=True)
class SensorTables:
    """Precomputed lookup tables of one wall map (build once per map, share between filters).

    Attributes
    ----------
    config : SensorConfig
    g : ndarray float32, shape (ny_pad * nx_pad,)
        Blurred G, padded by ``pad`` cells on every side, flattened row-major.
    offsets0 : ndarray int32, shape (n_r * n_angles,)
        Flat index offsets of the polar samples around a cell centre at heading 0
        (range-major: ``s = k * n_angles + j``).
    cos_tab, sin_tab : ndarray, shape (n_headings, n_angles)
        Direction cosines of polar angle j at heading bin b.
    r_cells : ndarray, shape (n_r,)
        Range bins in cells.
    s1, s2 : ndarray float64, shape (ny * nx,)
        Sum and sum of squares of the polar samples around each cell centre.
    ring : ndarray float32, shape (ny * nx, n_r)
        Polar samples around each cell centre summed over directions (range model).
    active : tuple (iy0, iy1, ix0, ix1)
        Cells where poses are scored (``s1``, ``s2``, ``ring`` filled); outside is off-map.
    pad : int
    shape : tuple (ny, nx) of the unpadded map
    origin_m, resolution_m : map geometry (see :class:`~mapping.wallmap.WallMap`)
    free_mask : ndarray bool, shape (ny, nx)
        Cells a robot can stand in (see :func:`free_space_mask`).
    """

    config: SensorConfig
    g: NDArray[np.float32]
    offsets0: NDArray[np.int32]
    cos_tab: FloatArray
    sin_tab: FloatArray
    r_cells: FloatArray
    s1: FloatArray
    s2: FloatArray
    ring: NDArray[np.float32]
    active: tuple[int, int, int, int]
    pad: int
    shape: tuple[int, int]
    origin_m: tuple[float, float]
    resolution_m: float
    free_mask: NDArray[np.bool_]

    @property
    def n_r(self) -> int:
        """Number of range bins."""
        return int(self.r_cells.shape[0])

    @property
    def n_samples(self) -> int:
        """Polar samples per pose, ``n_r * n_angles``."""
        return int(self.offsets0.shape[0])

    @property
    def nx_pad(self) -> int:
        """Padded row length."""
        return self.shape[1] + 2 * self.pad


@dataclass(frozen=True)
class Measurement:
    """A heat map prepared for scoring.

    Attributes
    ----------
    model : {"correlation", "range"}
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
    """

    model: Model
    direction_observable: bool
    dense: FloatArray
    idx: NDArray[np.int64]
    val: FloatArray
    m_mean: float
    m_norm: float


# ---- tables -----------------------------------------------------------------------------
def build_tables(
    wall_map: WallMap, config: SensorConfig, free_mask: NDArray[np.bool_] | None = None,
    active_margin_m: float = 1.0,
) -> SensorTables:
    """Precompute the polar lookup tables of ``wall_map``.

    Parameters
    ----------
    wall_map : WallMap
        The map G (paper eq. 5).
    config : SensorConfig
    free_mask : ndarray of bool, shape G.shape, optional
        Cells a robot can occupy; default :func:`free_space_mask`.
    active_margin_m : float
        Poses are scored within the free cells' bounding box grown by this margin; poses
        outside it count as off the map.
    """
    res = float(wall_map.resolution_m)
    ny, nx = wall_map.shape
    pad = int(math.ceil(config.max_range_m / res)) + 2
    g = wall_map.G.astype(np.float64)
    if config.map_blur_cells > 0:
        g = ndimage.gaussian_filter(g, config.map_blur_cells, mode="constant")
    g = np.clip(g, 0.0, None)
    g_pad = np.zeros((ny + 2 * pad, nx + 2 * pad), dtype=np.float32)
    g_pad[pad:pad + ny, pad:pad + nx] = g
    if free_mask is None:
        free_mask = free_space_mask(wall_map)
    elif free_mask.shape != (ny, nx):
        raise ValueError(f"free_mask must have shape {(ny, nx)}, got {free_mask.shape}")
    cos_tab, sin_tab = _direction_tables(config)
    r_cells = config.ranges_m / res
    nx_pad = nx + 2 * pad
    offsets0 = (np.floor(r_cells[:, None] * sin_tab[0][None, :] + 0.5) * nx_pad
                + np.floor(r_cells[:, None] * cos_tab[0][None, :] + 0.5)).astype(np.int32).ravel()
    n_r = r_cells.shape[0]
    s1, s2 = np.zeros(ny * nx), np.zeros(ny * nx)
    ring = np.zeros((ny * nx, n_r), dtype=np.float32)
    active = _active_box(free_mask, int(math.ceil(active_margin_m / res)))
    iy0, iy1, ix0, ix1 = active
    cells = np.indices((iy1 - iy0, ix1 - ix0)).reshape(2, -1).T + np.array([iy0, ix0])
    g_flat = g_pad.ravel()
    for s in range(0, cells.shape[0], 1024):
        c = cells[s:s + 1024]
        base = (c[:, 0] + pad) * (nx + 2 * pad) + c[:, 1] + pad
        q = g_flat[base[:, None] + offsets0[None, :]].astype(np.float64)
        flat = c[:, 0] * nx + c[:, 1]
        s1[flat] = q.sum(axis=1)
        s2[flat] = (q * q).sum(axis=1)
        ring[flat] = q.reshape(-1, n_r, config.n_angles).sum(axis=2)
    return SensorTables(
        config=config, g=g_flat, offsets0=offsets0, cos_tab=cos_tab, sin_tab=sin_tab,
        r_cells=r_cells, s1=s1, s2=s2, ring=ring, active=active,
        pad=pad,
        shape=(ny, nx), origin_m=(float(wall_map.origin_m[0]), float(wall_map.origin_m[1])),
        resolution_m=res, free_mask=np.asarray(free_mask, dtype=bool),
    )


def _active_box(free_mask: NDArray[np.bool_], margin: int) -> tuple[int, int, int, int]:
    """(iy0, iy1, ix0, ix1): bounding box of the free cells grown by ``margin`` cells."""
    ys, xs = np.nonzero(free_mask)
    ny, nx = free_mask.shape
    if ys.size == 0:
        return (0, ny, 0, nx)
    return (max(int(ys.min()) - margin, 0), min(int(ys.max()) + margin + 1, ny),
            max(int(xs.min()) - margin, 0), min(int(xs.max()) + margin + 1, nx))


def _direction_tables(config: SensorConfig) -> tuple[FloatArray, FloatArray]:
    """cos and sin of polar angle j at heading bin b, shape (n_headings, n_angles).

    Heading bin ``b * step + f`` is the polar grid rotated by ``b`` whole angle steps plus
    ``f`` fine steps; whole-step rotations are exact circular shifts of heading bin 0, so
    the exhaustive (FFT) scoring equals the per-pose scoring at those headings.
    """
    phi = 2.0 * np.pi * np.arange(config.n_angles) / config.n_angles
    step = config.n_headings // config.n_angles
    fine = 2.0 * np.pi * np.arange(step) / config.n_headings
    j = np.arange(config.n_angles)
    ang = np.stack([phi[(j + b) % config.n_angles] + fine[f]
                    for b in range(config.n_angles) for f in range(step)])
    return np.cos(ang), np.sin(ang)


def free_space_mask(
    wall_map: WallMap, wall_quantile: float = 0.999, wall_fraction: float = 0.5,
    clearance_m: float = 0.15, margin_m: float = 1.0,
) -> NDArray[np.bool_]:
    """Cells where a robot can stand: the mapped region, away from strong walls.

    The mapped region is where the mapping robot drove: a map built by
    :mod:`mapping.grid` covers the mapping poses plus ``params["grid"]["radius_m"]``, so the
    map's extent shrunk by that radius (then grown by ``margin_m``) bounds them. Within it,
    a cell is a wall when G exceeds ``wall_fraction`` of G's ``wall_quantile`` (only the
    strongest walls: back-projection arcs and the near-range blob along the path stay
    free), and free cells keep ``clearance_m`` from every wall cell.
    """
    ny, nx = wall_map.shape
    mask = np.ones((ny, nx), dtype=bool)
    radius = wall_map.params.get("grid", {}).get("radius_m") if isinstance(
        wall_map.params.get("grid"), dict) else None
    if isinstance(radius, int | float) and radius > margin_m:
        k = int((radius - margin_m) / wall_map.resolution_m)
        if 2 * k < min(ny, nx):
            mask[:] = False
            mask[k:ny - k, k:nx - k] = True
    g = ndimage.gaussian_filter(wall_map.G.astype(np.float64), 1.0)
    level = float(np.quantile(g[mask], wall_quantile))
    if level > 0:
        wall = g > wall_fraction * level
        dist = ndimage.distance_transform_edt(~wall) * wall_map.resolution_m
        free = mask & (dist >= clearance_m)
        if free.sum() >= 0.05 * mask.sum():
            mask = free
    labels, _ = ndimage.label(mask)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    inside = mask & ~np.isin(labels, border[border > 0])
    if inside.sum() >= 0.05 * mask.sum():
        mask = inside          # walls enclose a region: the robot is inside it
    return np.asarray(mask)


# ---- measurement --------------------------------------------------------------------------
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


# ---- scoring -------------------------------------------------------------------------------
def _index(tables: SensorTables, poses: FloatArray) -> tuple[
        NDArray[np.int64], FloatArray, FloatArray, NDArray[np.int64], NDArray[np.int64]]:
    """Padded flat index of each pose's nearest cell, its offset (ux, uy) from that cell's
    centre in cells, its heading bin and its map cell (-1 off the map)."""
    cfg = tables.config
    c = (poses[:, :2] - np.asarray(tables.origin_m)) / tables.resolution_m
    near = np.floor(c + 0.5)
    u = c - near
    u = np.where(np.abs(u) < 1e-9, 0.0, u)       # cell centres exactly
    ix, iy = near[:, 0].astype(np.int64), near[:, 1].astype(np.int64)
    iy0, iy1, ix0, ix1 = tables.active
    on = (ix >= ix0) & (ix < ix1) & (iy >= iy0) & (iy < iy1)
    hb = np.rint(poses[:, 2] * cfg.n_headings / (2 * np.pi)).astype(np.int64) % cfg.n_headings
    cell = np.where(on, iy * tables.shape[1] + ix, -1).astype(np.int64)
    base = np.where(on, (iy + tables.pad) * tables.nx_pad + ix + tables.pad, 0)
    return (base.astype(np.int64), np.ascontiguousarray(u[:, 0]),
            np.ascontiguousarray(u[:, 1]), hb, cell)


def _check(poses: FloatArray) -> FloatArray:
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must have shape (n, 3), got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise ValueError("poses contain NaN or inf")
    return poses


def score_poses(tables: SensorTables, measurement: Measurement, poses: FloatArray) -> FloatArray:
    """Correlation ``rho`` in [-1, 1] of the measurement with G at each pose (n, 3).

    NaN marks a pose off the map. Correlation model: one pose costs one gather and one
    multiply-add per kept measurement entry (numba, parallel over poses); the sample sums
    in the denominator are the pose's cell-centre values (heading-invariant up to the
    polar sampling). Range model: a dot product with the cell's ring profile; it does not
    depend on the heading at all.
    """
    poses = _check(poses)
    base, ux, uy, hb, cell = _index(tables, poses)
    if measurement.model == "range":
        return _k.score_range(tables.ring, cell, measurement.dense)
    return _k.score(tables.g, tables.nx_pad, tables.cos_tab, tables.sin_tab,
                    tables.r_cells, base, ux, uy, hb, cell, tables.s1, tables.s2, measurement.idx,
                    measurement.val, measurement.m_mean, measurement.m_norm, tables.n_samples)


def score_poses_numpy(tables: SensorTables, measurement: Measurement,
                      poses: FloatArray) -> FloatArray:
    """Plain numpy twin of :func:`score_poses` (for tests)."""
    poses = _check(poses)
    base, ux, uy, hb, cell = _index(tables, poses)
    if measurement.model == "range":
        return _k._range_numpy(tables.ring, cell, measurement.dense)
    return _k._score_numpy(tables.g, tables.nx_pad, tables.cos_tab,
                           tables.sin_tab, tables.r_cells, base, ux, uy, hb, cell, tables.s1,
                           tables.s2, measurement.idx, measurement.val, measurement.m_mean,
                           measurement.m_norm, tables.n_samples)


def log_likelihood(rho: FloatArray, config: SensorConfig, rho_ref: float = 1.0) -> FloatArray:
    """Tempered, floored log-likelihood ``log((1 - z) exp(beta (rho - rho_ref)) + z)``.

    Parameters
    ----------
    rho : ndarray
        Correlations from :func:`score_poses` (NaN = off the map).
    config : SensorConfig
        ``beta`` and ``z_rand``.
    rho_ref : float
        Correlation that gets the full likelihood 1. A particle filter passes the best
        correlation in its set, so the floor bounds the weight ratio one block can cause
        to ``1 / z_rand``; 1.0 (the perfect match) gives an absolute scale.

    NaN (off the map) maps to ``log(z_rand) - OFF_MAP_PENALTY``.
    """
    rho = np.asarray(rho, dtype=np.float64)
    z = config.z_rand
    ll = np.logaddexp(np.log1p(-z) + config.beta * (np.nan_to_num(rho, nan=-1.0) - rho_ref),
                      math.log(z))
    return np.where(np.isnan(rho), math.log(z) - OFF_MAP_PENALTY, ll)


def pose_log_likelihood(tables: SensorTables, measurement: Measurement, poses: FloatArray,
                        floor: bool = False) -> FloatArray:
    """``log p(heat map | pose, G)`` up to a constant, for each pose (n, 3).

    Without ``floor`` this is ``beta * rho`` (a smooth log-likelihood for MCMC; off-map
    poses get ``-inf``); with it, :func:`log_likelihood` relative to the best pose given.
    """
    rho = score_poses(tables, measurement, poses)
    if floor:
        ref = float(np.nanmax(rho)) if np.isfinite(rho).any() else 1.0
        return log_likelihood(rho, tables.config, ref)
    return np.where(np.isnan(rho), -np.inf, tables.config.beta * np.nan_to_num(rho))


def polar_prediction(tables: SensorTables, pose: FloatArray) -> FloatArray:
    """G sampled around one pose (3,): shape (n_r, n_angles), angles ``config.angles_rad``."""
    poses = _check(np.asarray(pose, dtype=np.float64).reshape(1, 3))
    base, ux, uy, hb, cell = _index(tables, poses)
    if cell[0] < 0:
        raise ValueError(f"pose {pose} is off the map")
    r = tables.r_cells[:, None]
    dx = np.floor(r * tables.cos_tab[hb[0]][None, :] + (ux[0] + 0.5))
    dy = np.floor(r * tables.sin_tab[hb[0]][None, :] + (uy[0] + 0.5))
    flat = base[0] + (dy * tables.nx_pad + dx).astype(np.int64)
    return tables.g[flat].astype(np.float64)


# ---- exhaustive scoring ---------------------------------------------------------------------
def cell_polar_samples(tables: SensorTables, cells: NDArray[np.int64]) -> NDArray[np.float32]:
    """Polar samples at heading 0 around cell centres ``cells`` (n, 2) as (iy, ix).

    Returns shape (n, n_r, n_angles).
    """
    base = (cells[:, 0] + tables.pad) * tables.nx_pad + cells[:, 1] + tables.pad
    out = tables.g[base[:, None] + tables.offsets0[None, :]]
    return out.reshape(cells.shape[0], tables.n_r, tables.config.n_angles)


def score_cells_all_headings(
    tables: SensorTables, measurement: Measurement, cells: NDArray[np.int64],
    chunk: int = 512,
) -> FloatArray:
    """``rho`` at every cell centre (n, 2 as iy, ix) and every heading ``2 pi m / n_angles``.

    The correlation model is a circular cross-correlation along the angle axis (FFT) and
    equals :func:`score_poses` at those poses; the range model does not depend on the
    heading (all columns equal). Returns (n, n_angles).
    """
    cfg = tables.config
    cells = np.asarray(cells, dtype=np.int64)
    flat = cells[:, 0] * tables.shape[1] + cells[:, 1]
    if measurement.model == "range":
        rho = _k._range_numpy(tables.ring, flat, measurement.dense)
        return np.repeat(rho[:, None], cfg.n_angles, axis=1)
    out = np.empty((cells.shape[0], cfg.n_angles))
    fm = np.conj(np.fft.rfft(measurement.dense.reshape(tables.n_r, cfg.n_angles), axis=1))
    n = tables.n_samples
    for s in range(0, cells.shape[0], chunk):
        q = cell_polar_samples(tables, cells[s:s + chunk]).astype(np.float64)
        num = np.fft.irfft((np.fft.rfft(q, axis=2) * fm[None]).sum(axis=1), n=cfg.n_angles,
                           axis=1)
        c = flat[s:s + chunk]
        s1, s2 = tables.s1[c], tables.s2[c]
        var = s2 - s1**2 / n
        den = measurement.m_norm * np.sqrt(np.maximum(var, 1e-18))
        out[s:s + chunk] = np.where(var[:, None] > 1e-18,
                                    (num - measurement.m_mean * s1[:, None]) / den[:, None], 0.0)
    return out
