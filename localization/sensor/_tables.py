"""Lookup tables of one wall map for the sensor model (:func:`build_tables`) and the free
space a global start draws from (:func:`free_space_mask`); see :mod:`localization.sensor`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import cast

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.spatial import Delaunay, QhullError

from localization.sensor._config import Model, SensorConfig
from localization.sensor._kernels import _ScoreTables, end_weight_rows
from mapping.forward import WallSet
from mapping.signal import SonarConfig
from mapping.wallmap import WallMap

FloatArray = NDArray[np.float64]

#: An end sigma above this (m) marks an open end (``WallFitParams.open_end_sigma_m``: 1 m;
#: ends the runs saw get a few centimetres).
OPEN_END_SIGMA_M = 0.5


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
    walls : WallSet
        The map's vector walls (empty for a raster-only map), read by the echo model.
    sonar : SonarConfig
        The sonar the echo model predicts for (carrier, block length, sound speed).
    coverage : ndarray bool, shape (ny, nx)
        Cells where the map has evidence (``WallMap.coverage``).
    wall_sigma : ndarray, shape (n_walls, 3)
        1-sigma uncertainty of each wall (``WallMap.wall_sigma``: normal offset m, angle
        rad, endpoints m), 0 where the map has none (an ideal map).
    end_sigma : ndarray, shape (n_walls, 2), or None
        1-sigma of each wall end along the wall (``WallMap.wall_end_sigma``): where the runs
        never looked past an end it is large, and the echo model runs the wall on
        (:func:`soft_end_walls`); None where the map does not say (``wall_sigma``'s endpoint
        sigma then applies to both ends).
    wall_side : ndarray int64, shape (n_walls,), or None
        The side each wall was heard from (``WallMap.wall_side``: +1 left of its direction,
        -1 right, 0 both); None where every wall is two-sided (an ideal map, an older map).
        The echo model predicts no echo that reaches a wall from a side never heard.
    complete : bool
        Whether the map claims every wall: a map made from geometry (a floor plan, a scene)
        rather than built from runs, which holds only the walls they heard (``WallMap``
        provenance lists its runs).
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
    walls: WallSet = field(default_factory=lambda: WallSet.from_array(np.zeros((0, 4))))
    sonar: SonarConfig = field(default_factory=SonarConfig)
    coverage: NDArray[np.bool_] | None = None
    wall_sigma: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    complete: bool = False
    end_sigma: FloatArray | None = None
    wall_side: NDArray[np.int64] | None = None

    @cached_property
    def soft_ends(self) -> tuple[WallSet, FloatArray]:
        """The walls with free ends run on, and each end's sigma (:func:`soft_end_walls`),
        computed once."""
        return soft_end_walls(self.walls, self.wall_sigma, end_sigma=self.end_sigma)

    @cached_property
    def open_ends(self) -> int:
        """Wall ends the runs never looked past: ``end_sigma`` above
        :data:`OPEN_END_SIGMA_M` (the wall fit gives such an end a metre, a seen one a few
        centimetres; 0 where the map says nothing of its ends). A map with one has free
        space it knows nothing of beyond it."""
        if self.end_sigma is None:
            return 0
        es = np.asarray(self.end_sigma, dtype=np.float64)
        return int(np.sum(np.isfinite(es) & (es > OPEN_END_SIGMA_M)))

    @cached_property
    def symmetries(self) -> FloatArray:
        """The walls' symmetries (:func:`wall_symmetries`), computed once."""
        return wall_symmetries(self.walls)

    @cached_property
    def free_cells(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Row and column indices of the free cells (``np.nonzero(free_mask)``), computed
        once: uniform draws over the free space come several times per block."""
        iy, ix = np.nonzero(self.free_mask)
        iy.setflags(write=False)
        ix.setflags(write=False)
        return iy, ix

    def free_at(self, xy_m: FloatArray) -> NDArray[np.bool_]:
        """Whether each point (n, 2) lies on a free cell (False off the map)."""
        return self._lookup(xy_m, self.free_mask)

    def covered(self, xy_m: FloatArray) -> NDArray[np.bool_]:
        """Whether each point (n, 2) lies on a cell with map evidence (False off the map)."""
        return self._lookup(xy_m, self.free_mask if self.coverage is None else self.coverage)

    def _lookup(self, xy_m: FloatArray, mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        ij = np.floor((xy - np.asarray(self.origin_m)) / self.resolution_m + 0.5).astype(
            np.int64)
        ny, nx = self.shape
        on = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
        out = np.zeros(xy.shape[0], dtype=bool)
        out[on] = mask[ij[on, 1], ij[on, 0]]
        return out

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

    @cached_property
    def _kernel(self) -> _ScoreTables:
        """The tables as the record the scoring kernels take (built once per instance)."""
        return _ScoreTables(g=self.g, nx_pad=self.nx_pad, cos_tab=self.cos_tab,
                            sin_tab=self.sin_tab, r_cells=self.r_cells, s1=self.s1, s2=self.s2,
                            ring=self.ring, n_samp=self.n_samples)


def build_tables(
    wall_map: WallMap, config: SensorConfig, free_mask: NDArray[np.bool_] | None = None,
    active_margin_m: float = 1.0, sonar: SonarConfig | None = None,
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
    sonar : SonarConfig, optional
        The sonar of the blocks to be scored (default ``SonarConfig()``, the paper's).

    Raises
    ------
    ValueError
        ``config.model == "echo"`` on a map without walls (a raster-only map: build it with
        the ``walls`` method).
    """
    if config.model == "echo" and wall_map.n_walls == 0:
        raise ValueError("model 'echo' needs a map with walls (walls_m is empty: build the map "
                         "with method 'walls', or use model 'correlation')")
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
        walls=_relative_walls(wall_map),
        sonar=SonarConfig() if sonar is None else sonar,
        coverage=np.asarray(wall_map.coverage, dtype=bool),
        wall_sigma=np.nan_to_num(np.asarray(wall_map.wall_sigma, dtype=np.float64).reshape(-1, 3)),
        complete=not wall_map.provenance.get("runs"),
        end_sigma=_end_sigma_of(wall_map),
        wall_side=_side_of(wall_map),
    )


def _side_of(wall_map: WallMap) -> NDArray[np.int64] | None:
    """``WallMap.wall_side``, None where every wall is two-sided."""
    side = wall_map.wall_side
    return side if np.any(side != 0) else None


def _end_sigma_of(wall_map: WallMap) -> FloatArray | None:
    """``WallMap.wall_end_sigma``, None where the map says nothing of its ends."""
    es = wall_map.wall_end_sigma
    return es if np.isfinite(es).any() else None


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

    A map built by :mod:`mapping.grid` covers the mapping poses plus
    ``params["grid"]["radius_m"]``, so the map's extent shrunk by that radius (then grown by
    ``margin_m``) bounds them. A wall map built from runs adds what the runs observed
    (``WallMap.coverage``) within the walls they found (the convex hull of the fitted walls'
    ends), and keeps of the box only what they observed: a robot may stand anywhere the map
    has evidence of, not only near where the mapping robot drove. Measured on the
    benchmark's built maps, the box alone held 18-56 % of the poses of parlour-mirror,
    parlour-line, foyer-wing and arcadia-open, so a global start could never find the robot
    there. Within the region, a cell is a wall when G exceeds
    ``wall_fraction`` of G's ``wall_quantile`` (only the strongest walls: back-projection
    arcs and the near-range blob along the path stay free), and free cells keep
    ``clearance_m`` from every wall cell.
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
    observed = _observed_within_walls(wall_map)
    if observed is not None:
        mask = np.asarray(wall_map.coverage, dtype=bool) & (mask | observed)
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


def _observed_within_walls(wall_map: WallMap) -> NDArray[np.bool_] | None:
    """Cells of a wall map built from runs that the runs observed and that lie within the
    convex hull of the fitted walls' ends; None for a map not built from runs, without
    walls or coverage, or whose walls span no area."""
    if not wall_map.provenance.get("runs") or wall_map.n_walls == 0:
        return None
    coverage = np.asarray(wall_map.coverage, dtype=bool)
    if coverage.shape != wall_map.shape or coverage.all() or not coverage.any():
        return None
    ends = np.asarray(wall_map.walls_m, dtype=np.float64).reshape(-1, 2)
    try:
        hull = Delaunay(ends)
    except QhullError:
        return None                      # collinear walls: no area to stand in
    ny, nx = wall_map.shape
    iy, ix = np.nonzero(coverage)
    xy = (np.asarray(wall_map.origin_m, dtype=np.float64)
          + np.column_stack([ix, iy]) * float(wall_map.resolution_m))
    inside = hull.find_simplex(xy) >= 0
    out = np.zeros((ny, nx), dtype=bool)
    out[iy[inside], ix[inside]] = True
    return out if out.any() else None


def _relative_walls(wall_map: WallMap) -> WallSet:
    """The map's walls with strengths relative to the strongest (the echo model compares
    echo levels within a pose, so only ratios matter, and products over bounces stay <= 1)."""
    s = np.asarray(wall_map.wall_strength, dtype=np.float64)
    top = float(s.max()) if s.size else 0.0
    return WallSet.from_array(wall_map.walls_m, s / top if top > 0 else np.ones_like(s))


def soft_end_walls(walls: WallSet, wall_sigma: FloatArray, join_m: float = 0.05,
                   reach: float = 2.5, end_sigma: FloatArray | None = None
                   ) -> tuple[WallSet, FloatArray]:
    """Walls whose free ends (no other wall's end within ``join_m``) are run on by ``reach``
    times their endpoint sigma (``wall_sigma[:, 2]``), and the sigma of each end (n, 2; 0
    for a joined end or a map without one).

    A fitted wall's free end is known only to its endpoint sigma (where the specular point
    left the observed stretch). The echo model predicts the run-on walls and weighs each
    bounce by the probability that the wall reaches it (:func:`end_weights`), so a pose
    near the end of a wall is neither forced to hear it nor forbidden to.

    ``end_sigma`` (n, 2), where given and finite, is each end's own sigma
    (``WallMap.wall_end_sigma``): an end the runs never looked past has a sigma of a metre
    and is run on by up to ``reach`` times that, stopping at the first other wall it meets.
    Measured on the held-out foundry's built map, whose west wall ended where the mapped
    curve's specular points did (1.77 m of 6.8 m): a robot near the west wall heard it where
    the map had none, its mirror image 10 m east heard the east wall where the map had one,
    and global starts reported the mirror ``converged`` (106 blocks over 3 starts).
    """
    seg = np.asarray(walls.segments_m, dtype=np.float64).reshape(-1, 2, 2)
    n = seg.shape[0]
    sig = np.zeros((n, 2))
    if n == 0 or wall_sigma.shape != (n, 3):
        return walls, sig
    ends = seg.reshape(-1, 2)
    d = np.hypot(*(ends[:, None, :] - ends[None, :, :]).transpose(2, 0, 1))
    own = np.repeat(np.arange(n), 2)
    d[own[:, None] == own[None, :]] = np.inf
    free = (d.min(axis=1) > join_m).reshape(n, 2)
    per_end = (np.nan_to_num(wall_sigma[:, 2])[:, None].repeat(2, axis=1)
               if end_sigma is None or end_sigma.shape != (n, 2)
               else np.where(np.isfinite(end_sigma), end_sigma,
                             np.nan_to_num(wall_sigma[:, 2])[:, None]))
    sig = np.where(free, per_end, 0.0)
    u = seg[:, 1] - seg[:, 0]
    length = np.hypot(u[:, 0], u[:, 1])
    u = u / np.maximum(length, 1e-12)[:, None]
    out = seg.copy()
    for i in range(n):
        for end, sign in ((0, -1.0), (1, 1.0)):
            if sig[i, end] <= 0.0:
                continue
            run = reach * sig[i, end]
            # a run-on end stops at the first other wall it meets
            tip = seg[i, end]
            for j in range(n):
                if j != i:
                    t = _ray_hits(tip, sign * u[i], seg[j])
                    if t is not None and t < run:
                        run = t
            out[i, end] = tip + sign * run * u[i]
    return WallSet(out, walls.strength), sig


def _ray_hits(p: FloatArray, d: FloatArray, s: FloatArray) -> float | None:
    """Distance along the unit ray ``p + t d`` (t >= 0) to the segment ``s`` (2, 2), or
    None when it misses."""
    e = s[1] - s[0]
    den = d[0] * e[1] - d[1] * e[0]
    if abs(den) < 1e-12:
        return None
    w = s[0] - p
    t = (w[0] * e[1] - w[1] * e[0]) / den
    v = (w[0] * d[1] - w[1] * d[0]) / den
    return float(t) if t >= 0.0 and 0.0 <= v <= 1.0 else None


def end_weights(walls: WallSet, end_sigma: FloatArray, wall_idx: NDArray[np.int64],
                points_m: FloatArray, parallel: bool = False) -> FloatArray:
    """Probability that the fitted wall reaches each bounce point: for the bounce on wall
    w at P, ``Phi(s0 / sigma0) Phi(s1 / sigma1)`` with ``s0, s1`` the distances from P to
    the fitted ends of ``walls`` (not run on) along it, positive inside; 1 for joined ends.
    Product over a path's bounces; ``wall_idx`` (..., K) with -1 padding, ``points_m``
    (..., K, 2). numba kernel (``_kernels._end_weights_kernel``); its numpy twin is in
    ``tests/localization/sensor/naive.py``; ``parallel``: over numba's threads, the same
    numbers)."""
    if not np.any(end_sigma > 0):
        return np.ones(wall_idx.shape[:-1])
    return end_weight_rows(np.asarray(walls.segments_m, dtype=np.float64).reshape(-1, 2, 2),
                           np.asarray(end_sigma, dtype=np.float64), np.asarray(wall_idx),
                           np.asarray(points_m, dtype=np.float64), parallel)


def uniform_free_poses(tables: SensorTables, n: int, rng: np.random.Generator) -> FloatArray:
    """``n`` poses uniform over the free cells of the map, headings uniform in (-pi, pi]."""
    iy, ix = tables.free_cells
    pick = rng.integers(0, iy.size, size=n)
    u = rng.random((n, 3))
    out = np.empty((n, 3))
    out[:, 0] = tables.origin_m[0] + (ix[pick] + u[:, 0] - 0.5) * tables.resolution_m
    out[:, 1] = tables.origin_m[1] + (iy[pick] + u[:, 1] - 0.5) * tables.resolution_m
    out[:, 2] = -np.pi + 2 * np.pi * u[:, 2]
    return out


def resolve_model(wall_map: WallMap, model: str) -> Model:
    """The sensor model to use on ``wall_map``: ``"auto"`` is the physical ``echo`` model on a
    map with walls and the G ``correlation`` model on a raster-only map; any other name is
    returned as given (``SensorConfig`` validates it)."""
    if model == "auto":
        return "echo" if wall_map.n_walls > 0 else "correlation"
    if model not in ("echo", "correlation", "range"):
        raise ValueError(f"model must be 'auto', 'echo', 'correlation' or 'range', got {model!r}")
    return cast(Model, model)


def wall_symmetries(walls: WallSet, tol_m: float = 0.15) -> FloatArray:
    """The rigid motions (rotations and reflections, not the identity) that map the wall set
    onto itself within ``tol_m``: a symmetric room's twins, which no sensor can tell apart.

    Candidates map one wall onto another of the same length (both orientations, rotation
    or reflection); one is kept when every wall lands on some wall. Returns (k, 2, 3)
    affine matrices ``[R | t]`` acting on points (``R`` orthogonal, det +1 or -1).
    """
    seg = np.asarray(walls.segments_m, dtype=np.float64).reshape(-1, 2, 2)
    n = seg.shape[0]
    length = np.hypot(*(seg[:, 1] - seg[:, 0]).T)
    found: list[FloatArray] = []

    def onto(a0: FloatArray, a1: FloatArray, b0: FloatArray, b1: FloatArray,
             flip: bool) -> FloatArray:
        ua, ub = a1 - a0, b1 - b0
        ang = math.atan2(ub[1], ub[0]) - (math.atan2(-ua[1], ua[0]) if flip
                                          else math.atan2(ua[1], ua[0]))
        c, s = math.cos(ang), math.sin(ang)
        rot = np.array([[c, -s], [s, c]])
        r = rot @ np.diag([1.0, -1.0]) if flip else rot
        return np.column_stack([r, b0 - r @ a0])

    def maps_all(m: FloatArray) -> bool:
        img = seg @ m[:, :2].T + m[:, 2]
        for k in range(n):
            d1 = np.abs(seg - img[k][None]).max(axis=(1, 2))
            d2 = np.abs(seg - img[k][None, ::-1]).max(axis=(1, 2))
            if min(d1.min(), d2.min()) > tol_m:
                return False
        return True

    if n == 0:
        return np.zeros((0, 2, 3))
    i = int(np.argmax(length))          # the longest wall must land on a wall as long
    for j in range(n):
        if abs(length[j] - length[i]) > tol_m:
            continue
        for b0, b1 in ((seg[j, 0], seg[j, 1]), (seg[j, 1], seg[j, 0])):
            for flip in (False, True):
                m = onto(seg[i, 0], seg[i, 1], b0, b1, flip)
                identity = np.allclose(m, np.array([[1.0, 0, 0], [0, 1.0, 0]]), atol=1e-6)
                if identity or any(np.allclose(m, f, atol=tol_m) for f in found):
                    continue
                if maps_all(m):
                    found.append(m)
    return np.asarray(found).reshape(-1, 2, 3)


def symmetric_poses(symmetries: FloatArray, pose: FloatArray) -> FloatArray:
    """The images (k, 3) of ``pose`` (x, y, heading) under each symmetry (k, 2, 3)."""
    pose = np.asarray(pose, dtype=np.float64)
    if symmetries.shape[0] == 0:
        return np.zeros((0, 3))
    xy = symmetries[:, :, :2] @ pose[:2] + symmetries[:, :, 2]
    d = symmetries[:, :, :2] @ np.array([math.cos(pose[2]), math.sin(pose[2])])
    return np.column_stack([xy, np.arctan2(d[:, 1], d[:, 0])])
