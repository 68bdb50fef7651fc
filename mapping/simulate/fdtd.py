"""FDTD reference simulator of a moving sonar (paper Sec. 3, eqs. 6-17, Table 2).

A 2-D staggered-grid p-q FDTD (eqs. 9-11) with a graded perfectly matched layer on the
outer border, walls as rigid (or finite-impedance) velocity nodes, and the moving source and
receiver placed on the grid by the direct method with bilinear weights (eqs. 12-17). Two
fields advance in the same sweep: one with the walls and one without; their difference at
the receiver is the received signal without the direct wave, as in the paper.

Conventions
-----------
- Cell ``(i, j)`` has its pressure node at ``origin_m + (i, j) * grid_step_m``; ``qx[i, j]``
  sits half a cell before it in x, ``qy[i, j]`` half a cell before it in y. Cell centres are
  placed at odd multiples of ``grid_step_m / 2`` so that walls on round coordinates fall on
  velocity nodes, never on pressure nodes.
- Bilinear weights (eqs. 12-17). The paper writes ``zeta = 2 (x - floor(x / dx)) / dx - 1``,
  mixing metres and cell indices; the intended coordinate, used here, is
  ``u = (x - x0) / dx``, ``zeta = 2 (u - floor(u)) - 1`` (and ``eta`` likewise), with the four
  nodes ``floor(u)`` and ``floor(u) + 1`` (not ``ceil``, which collapses onto ``floor`` on a
  node). The weights ``(1 -+ zeta)(1 -+ eta) / 4`` are non-negative and sum to 1.
- Source: a mass (volume-velocity) source ``dp/dt += rho c^2 Q(t) delta(x - x_s)``. ``Q`` is
  the transmitted signal (``mapping.signal``) filtered so that the free-field pressure far
  from a static source is ``s(t - r / c) / sqrt(r)`` (r in metres): the 2-D Green's function
  has a half-derivative and a -pi/4 phase, which the filter undoes. The filter also
  band-limits the signal to what the grid carries (raised-cosine taper to ``max_frequency``).
- Denormals: the pressure is stored with a constant offset (``1e-6`` of the source scale);
  differences of stored pressures are then either zero or far above the subnormal range, and
  the decaying fields inside the PML are flushed to zero below ``1e-30``. The benchmark
  measures the effect.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq

from mapping.runfile import Run
from mapping.signal import SonarConfig, tx_period
from mapping.simulate import _fdtd_kernels as _k
from mapping.simulate.base import PathTable, SceneLike, SimBlock, TrajectoryLike, assemble_run

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_COURANT_LIMIT = 1.0 / math.sqrt(2.0)
_FLUSH = 1e-30
_RESAMPLE_HALF_WIDTH = 96
_TABLE_UPSAMPLE = 32
#: Below this many field cells the kernel runs on one thread (per-step barriers dominate).
_SMALL_GRID_CELLS = 200_000


# ---- configuration ------------------------------------------------------------------------
@dataclass(frozen=True)
class FdtdConfig:
    """Parameters of the FDTD engine (defaults: paper Table 2, grid fitted to the scene).

    Parameters
    ----------
    grid_step_m : float
        Grid step dx = dy (Table 2: 5 mm).
    time_step_s : float
        Time step dt (Table 2: 8.333 us = 1 / 120 kHz). ``c dt / dx`` must not exceed
        1 / sqrt(2) (2-D Courant limit).
    density_kg_m3 : float
        Density rho_0 of air (Table 2: 1.293).
    sound_speed_m_s : float or None
        c_a; None takes it from the SonarConfig (340 m/s, Table 2).
    pml_cells : int
        Thickness of the graded PML on each outer edge (>= 0; 0 gives a rigid box).
    pml_order : float
        Polynomial grading exponent of the PML absorption profile.
    pml_reflection : float
        Design normal-incidence reflection of the continuous PML, sets sigma_max.
    margin_m : float
        Free space kept around the scene's walls and the path, inside the PML.
    dtype : str
        "float32" (default) or "float64" fields.
    max_frequency_hz : float or None
        Upper edge of the injected band; None: the lower of the signal's band edge
        (carrier + chip rate) and the frequency at ``min_points_per_wavelength``.
    min_points_per_wavelength : float
        Grid limit used when ``max_frequency_hz`` is None.
    warn_points_per_wavelength : float
        Below this many points per wavelength at the injected band edge a warning is issued.
    warmup_s : float or None
        Simulated time before t = 0 so that echoes of the (endless) transmission are present
        from the first sample; None: two domain diagonals of travel time.
    denormal_guard : bool
        Keep fields out of the subnormal range (offset pressure, flush inside the PML).
    """

    grid_step_m: float = 0.005
    time_step_s: float = 1.0 / 120_000.0
    density_kg_m3: float = 1.293
    sound_speed_m_s: float | None = None
    pml_cells: int = 24
    pml_order: float = 3.0
    pml_reflection: float = 1e-6
    margin_m: float = 0.3
    dtype: str = "float32"
    max_frequency_hz: float | None = None
    min_points_per_wavelength: float = 4.0
    warn_points_per_wavelength: float = 10.0
    warmup_s: float | None = None
    denormal_guard: bool = True

    def __post_init__(self) -> None:
        for name in ("grid_step_m", "time_step_s", "density_kg_m3", "min_points_per_wavelength",
                     "pml_order"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"FdtdConfig.{name} must be a positive finite number, got {v!r}")
        if self.sound_speed_m_s is not None and not self.sound_speed_m_s > 0:
            raise ValueError(
                f"FdtdConfig.sound_speed_m_s must be > 0, got {self.sound_speed_m_s}")
        if not (isinstance(self.pml_cells, int) and self.pml_cells >= 0):
            raise ValueError(f"FdtdConfig.pml_cells must be an integer >= 0, got {self.pml_cells}")
        if not 0 < self.pml_reflection < 1:
            raise ValueError(
                f"FdtdConfig.pml_reflection must be in (0, 1), got {self.pml_reflection}")
        if self.margin_m < 0:
            raise ValueError(f"FdtdConfig.margin_m must be >= 0, got {self.margin_m}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(
                f"FdtdConfig.dtype must be 'float32' or 'float64', got {self.dtype!r}")
        if self.max_frequency_hz is not None and not self.max_frequency_hz > 0:
            raise ValueError(
                f"FdtdConfig.max_frequency_hz must be > 0, got {self.max_frequency_hz}")
        if self.warmup_s is not None and not self.warmup_s >= 0:
            raise ValueError(f"FdtdConfig.warmup_s must be >= 0, got {self.warmup_s}")

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dictionary of the fields."""
        return asdict(self)

    def speed(self, sonar: SonarConfig) -> float:
        """The sound speed in use (own value, else the sonar's)."""
        return float(self.sound_speed_m_s or sonar.sound_speed_m_s)


def courant_number(fdtd: FdtdConfig, c: float) -> float:
    """Courant number ``c dt / dx`` (0.567 for Table 2)."""
    return c * fdtd.time_step_s / fdtd.grid_step_m


def check_courant(fdtd: FdtdConfig, c: float) -> float:
    """Return the Courant number; ``ValueError`` above the 2-D limit 1 / sqrt(2)."""
    s = courant_number(fdtd, c)
    if s > _COURANT_LIMIT:
        raise ValueError(
            f"FdtdConfig: Courant number c*time_step_s/grid_step_m = {s:.4f} exceeds the 2-D "
            f"stability limit 1/sqrt(2) = {_COURANT_LIMIT:.4f}; reduce time_step_s below "
            f"{_COURANT_LIMIT * fdtd.grid_step_m / c:.4g} s"
        )
    return s


# ---- numerical dispersion -----------------------------------------------------------------
def numerical_wavenumber(freq_hz: float, angle_rad: float, grid_step_m: float,
                         time_step_s: float, c: float) -> float:
    """Wavenumber |k| of the staggered scheme at ``freq_hz`` along ``angle_rad``.

    Solves the dispersion relation of eqs. 9-11,
    ``sin^2(w dt / 2) / (c dt)^2 = [sin^2(kx dx / 2) + sin^2(ky dx / 2)] / dx^2``.
    """
    w, dx, dt = 2 * math.pi * freq_hz, grid_step_m, time_step_s
    ca, sa = abs(math.cos(angle_rad)), abs(math.sin(angle_rad))
    rhs = (math.sin(w * dt / 2) * dx / (c * dt)) ** 2

    def g(k: float) -> float:
        return math.sin(k * ca * dx / 2) ** 2 + math.sin(k * sa * dx / 2) ** 2 - rhs

    k_hi = math.pi / (dx * max(ca, sa))
    if g(k_hi) < 0:
        raise ValueError(f"freq_hz={freq_hz:g} is above the grid's cut-off along {angle_rad} rad")
    return float(brentq(g, 1e-12, k_hi, xtol=1e-12, rtol=1e-14))


def numerical_group_velocity(freq_hz: float, angle_rad: float, grid_step_m: float,
                             time_step_s: float, c: float) -> float:
    """Group velocity dw/d|k| of the grid at ``freq_hz`` along ``angle_rad`` (m/s)."""
    df = 1e-4 * freq_hz
    k1 = numerical_wavenumber(freq_hz - df, angle_rad, grid_step_m, time_step_s, c)
    k2 = numerical_wavenumber(freq_hz + df, angle_rad, grid_step_m, time_step_s, c)
    return 2 * math.pi * 2 * df / (k2 - k1)


@dataclass(frozen=True)
class FdtdReport:
    """Set-up numbers of an FDTD run (printed by the CLI).

    ``group_velocity_error_*`` are ``v_g / c - 1`` along the grid axis and the diagonal
    (negative = slow).
    """

    shape: tuple[int, int]
    origin_m: tuple[float, float]
    grid_step_m: float
    time_step_s: float
    courant: float
    signal_band_edge_hz: float
    injected_max_hz: float
    points_per_wavelength_signal_edge: float
    points_per_wavelength_injected_edge: float
    group_velocity_error_carrier: tuple[float, float]
    group_velocity_error_injected_edge: tuple[float, float]
    n_steps: int
    warmup_steps: int
    field_bytes: int

    def lines(self) -> list[str]:
        """Human-readable summary, one item per line."""
        gc, ge = self.group_velocity_error_carrier, self.group_velocity_error_injected_edge
        return [
            f"grid {self.shape[0]} x {self.shape[1]} cells of {self.grid_step_m * 1e3:g} mm, "
            f"dt {self.time_step_s * 1e6:.4g} us, Courant {self.courant:.3f}",
            f"points per wavelength: {self.points_per_wavelength_signal_edge:.2f} at the signal "
            f"band edge {self.signal_band_edge_hz / 1e3:g} kHz, "
            f"{self.points_per_wavelength_injected_edge:.2f} at the injected edge "
            f"{self.injected_max_hz / 1e3:.3g} kHz",
            f"group-velocity error at the carrier: {gc[0] * 100:+.2f} % (axis) "
            f"{gc[1] * 100:+.2f} % (diagonal); at the injected edge {ge[0] * 100:+.2f} % / "
            f"{ge[1] * 100:+.2f} %",
            f"{self.n_steps} steps ({self.warmup_steps} warm-up), "
            f"{self.field_bytes / 1e6:.1f} MB of fields",
        ]


def injected_band(sonar: SonarConfig, fdtd: FdtdConfig) -> tuple[float, float]:
    """(signal band edge, injected band edge) in Hz."""
    c = fdtd.speed(sonar)
    edge = min(sonar.carrier_hz + sonar.chip_rate_hz, sonar.fs_hz / 2)
    if fdtd.max_frequency_hz is not None:
        return edge, float(fdtd.max_frequency_hz)
    grid_limit = c / (fdtd.min_points_per_wavelength * fdtd.grid_step_m)
    return edge, float(min(edge, grid_limit))


# ---- grid, walls, stencils ----------------------------------------------------------------
@dataclass(frozen=True)
class FdtdGrid:
    """Pressure nodes at ``origin_m + (i, j) * grid_step_m``, i < nx, j < ny; the outer
    ``pml_cells`` on each side are the PML."""

    origin_m: tuple[float, float]
    shape: tuple[int, int]
    grid_step_m: float
    pml_cells: int

    def interior_bounds_m(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the non-PML region (pressure node coordinates)."""
        n, dx = self.pml_cells, self.grid_step_m
        x0, y0 = self.origin_m
        nx, ny = self.shape
        return (x0 + n * dx, x0 + (nx - 1 - n) * dx, y0 + n * dx, y0 + (ny - 1 - n) * dx)


def fit_grid(points_m: FloatArray, fdtd: FdtdConfig) -> FdtdGrid:
    """Smallest grid holding ``points_m`` (n, 2) plus the margin plus the PML.

    Cell centres sit at odd multiples of dx / 2 (walls on round coordinates land on
    velocity nodes).
    """
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    if pts.size == 0 or not np.all(np.isfinite(pts)):
        raise ValueError("points_m must be a non-empty finite (n, 2) array")
    dx = fdtd.grid_step_m
    lo = pts.min(axis=0) - fdtd.margin_m
    hi = pts.max(axis=0) + fdtd.margin_m
    first = np.floor(lo / dx - 0.5) - fdtd.pml_cells
    last = np.ceil(hi / dx - 0.5) + fdtd.pml_cells
    shape = (int(last[0] - first[0]) + 1, int(last[1] - first[1]) + 1)
    origin = ((first[0] + 0.5) * dx, (first[1] + 0.5) * dx)
    return FdtdGrid(origin_m=(float(origin[0]), float(origin[1])), shape=shape,
                    grid_step_m=dx, pml_cells=fdtd.pml_cells)


def rasterize_walls(segments_m: FloatArray, grid: FdtdGrid) -> tuple[NDArray[np.bool_],
                                                                     NDArray[np.bool_]]:
    """Velocity nodes whose link between two pressure nodes crosses a wall segment.

    Returns ``(wx, wy)`` of shapes (nx + 1, ny) and (nx, ny + 1). Every link intersecting a
    segment is blocked, so a closed polygon is watertight on the grid.
    """
    seg = np.asarray(segments_m, dtype=np.float64).reshape(-1, 2, 2)
    nx, ny = grid.shape
    dx = grid.grid_step_m
    x0, y0 = grid.origin_m
    wx = np.zeros((nx + 1, ny), dtype=bool)
    wy = np.zeros((nx, ny + 1), dtype=bool)
    for (px, py), (qx, qy) in seg:
        _mark_links(wx, px, py, qx, qy, x0, y0, dx, nx, ny)
        _mark_links(wy.T, py, px, qy, qx, y0, x0, dx, ny, nx)
    return wx, wy


def _mark_links(w: NDArray[np.bool_], px: float, py: float, qx: float, qy: float,
                x0: float, y0: float, dx: float, nx: int, ny: int) -> None:
    """Mark x-links (node rows j at y0 + j dx) crossed by segment (px,py)-(qx,qy)."""
    if qy == py:
        return
    j = np.arange(max(0, math.ceil((min(py, qy) - y0) / dx)),
                  min(ny - 1, math.floor((max(py, qy) - y0) / dx)) + 1)
    if j.size == 0:
        return
    t = (y0 + j * dx - py) / (qy - py)
    u = (px + t * (qx - px) - x0) / dx  # crossing in pressure-node units
    i = np.floor(u).astype(np.int64) + 1  # link i joins nodes i-1 and i
    ok = (i >= 1) & (i <= nx - 1)
    w[i[ok], j[ok]] = True
    exact = ok & (u == np.floor(u)) & (i - 1 >= 1)
    w[i[exact] - 1, j[exact]] = True


def bilinear_stencil(points_m: FloatArray, grid: FdtdGrid) -> tuple[IntArray, IntArray,
                                                                   FloatArray]:
    """Nodes and weights of the direct method (eqs. 12-17) for points (n, 2).

    Returns ``(i, j, w)`` each (n, 4) in the order (floor, floor), (floor+1, floor),
    (floor+1, floor+1), (floor, floor+1); ``w = (1 -+ zeta)(1 -+ eta) / 4`` with
    ``zeta = 2 (u - floor(u)) - 1``, ``u = (x - x0) / dx``; rows sum to 1.
    """
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    u = (pts[:, 0] - grid.origin_m[0]) / grid.grid_step_m
    v = (pts[:, 1] - grid.origin_m[1]) / grid.grid_step_m
    i0, j0 = np.floor(u), np.floor(v)
    nx, ny = grid.shape
    if np.any((i0 < 0) | (i0 + 1 > nx - 1) | (j0 < 0) | (j0 + 1 > ny - 1)):
        raise ValueError("points_m: a source or receiver position lies outside the grid")
    zeta, eta = 2 * (u - i0) - 1, 2 * (v - j0) - 1
    ii = i0.astype(np.int64)[:, None] + np.array([0, 1, 1, 0])
    jj = j0.astype(np.int64)[:, None] + np.array([0, 0, 1, 1])
    w = np.stack([(1 - zeta) * (1 - eta), (1 + zeta) * (1 - eta),
                  (1 + zeta) * (1 + eta), (1 - zeta) * (1 + eta)], axis=1) / 4
    return ii, jj, w


# ---- coefficients -------------------------------------------------------------------------
@dataclass(frozen=True)
class FdtdCoefficients:
    """Update coefficients (eqs. 9-11 with the PML), in the field dtype."""

    aqx: NDArray[Any]
    bqx: NDArray[Any]
    aqy: NDArray[Any]
    bqy: NDArray[Any]
    apx: NDArray[Any]
    bpx: NDArray[Any]
    apy: NDArray[Any]
    bpy: NDArray[Any]
    kp: float
    kq: float


def _pml_sigma(pos: NDArray[Any], n: int, npml: int, fdtd: FdtdConfig, c: float) -> FloatArray:
    """Absorption sigma (1/s) at node positions ``pos`` in pressure-node units."""
    if npml == 0:
        return np.zeros_like(pos)
    depth = np.maximum(np.maximum((npml - 0.5) - pos, pos - (n - npml - 0.5)), 0.0) / npml
    width = npml * fdtd.grid_step_m
    smax = (fdtd.pml_order + 1) * c * math.log(1 / fdtd.pml_reflection) / (2 * width)
    return np.asarray(smax * depth ** fdtd.pml_order)


def make_coefficients(grid: FdtdGrid, fdtd: FdtdConfig, c: float) -> FdtdCoefficients:
    """PML-graded coefficients: ``a = (1 - s dt/2) / (1 + s dt/2)``, ``b = k / (1 + s dt/2)``."""
    dt, dx, rho = fdtd.time_step_s, fdtd.grid_step_m, fdtd.density_kg_m3
    dtype = np.dtype(fdtd.dtype)
    kq, kp = dt / (rho * dx), rho * c * c * dt / dx
    nx, ny = grid.shape
    npml = grid.pml_cells

    def ab(sig: FloatArray, k: float) -> tuple[NDArray[Any], NDArray[Any]]:
        h = sig * dt / 2
        return ((1 - h) / (1 + h)).astype(dtype), (k / (1 + h)).astype(dtype)

    aqx, bqx = ab(_pml_sigma(np.arange(nx + 1) - 0.5, nx, npml, fdtd, c), kq)
    aqy, bqy = ab(_pml_sigma(np.arange(ny + 1) - 0.5, ny, npml, fdtd, c), kq)
    apx, bpx = ab(_pml_sigma(np.arange(nx, dtype=float), nx, npml, fdtd, c), kp)
    apy, bpy = ab(_pml_sigma(np.arange(ny, dtype=float), ny, npml, fdtd, c), kp)
    return FdtdCoefficients(aqx, bqx, aqy, bqy, apx, bpx, apy, bpy,
                            float(dtype.type(kp)), float(dtype.type(kq)))


@dataclass(frozen=True)
class WallNodes:
    """Walls on the grid: rigid velocity nodes and finite-impedance pressure cells."""

    wx: NDArray[np.bool_]
    wy: NDArray[np.bool_]
    beta: FloatArray  # (nx, ny): implicit impedance coefficient, 0 where none

    @classmethod
    def none(cls, grid: FdtdGrid) -> WallNodes:
        """No walls."""
        nx, ny = grid.shape
        return cls(np.zeros((nx + 1, ny), bool), np.zeros((nx, ny + 1), bool), np.zeros((nx, ny)))


def wall_nodes(segments_m: FloatArray, impedance_pa_s_m: FloatArray, grid: FdtdGrid,
               fdtd: FdtdConfig, c: float) -> WallNodes:
    """Rasterize walls; a finite impedance Z adds ``beta = rho c^2 dt / (2 Z dx)`` to the
    pressure cells on both sides (locally reacting surface, p = Z q_n on each face)."""
    seg = np.asarray(segments_m, dtype=np.float64).reshape(-1, 2, 2)
    z = np.broadcast_to(np.asarray(impedance_pa_s_m, dtype=np.float64), (seg.shape[0],))
    if np.any(~(z > 0)):
        raise ValueError("impedance_pa_s_m must be > 0 (inf for rigid walls)")
    wx_all, wy_all = rasterize_walls(seg, grid)
    nx, ny = grid.shape
    beta = np.zeros((nx, ny))
    k = fdtd.density_kg_m3 * c * c * fdtd.time_step_s / (2 * fdtd.grid_step_m)
    for s, zk in zip(seg, z, strict=True):
        if not math.isfinite(zk):
            continue
        wx, wy = rasterize_walls(s[None], grid)
        ix, jx = np.nonzero(wx)
        np.add.at(beta, (ix - 1, jx), k / zk)
        np.add.at(beta, (ix, jx), k / zk)
        iy, jy = np.nonzero(wy)
        np.add.at(beta, (iy, jy - 1), k / zk)
        np.add.at(beta, (iy, jy), k / zk)
    return WallNodes(wx_all, wy_all, beta)


def _csr_rows(mask: NDArray[np.bool_]) -> tuple[IntArray, IntArray]:
    rows, cols = np.nonzero(mask)
    ptr = np.zeros(mask.shape[0] + 1, dtype=np.int64)
    np.add.at(ptr, rows + 1, 1)
    return np.cumsum(ptr), cols.astype(np.int64)


# ---- the solver ---------------------------------------------------------------------------
class FdtdSolver:
    """Fields of one grid (``n_fields`` = 2: with walls, without) and their time stepping.

    A thin stateful object over :func:`_k._run_steps`; ``backend="numpy"`` uses the plain
    numpy twin instead (tests, benchmark baseline).
    """

    def __init__(self, grid: FdtdGrid, fdtd: FdtdConfig, c: float, walls: WallNodes | None = None,
                 n_fields: int = 2, backend: str = "numba") -> None:
        check_courant(fdtd, c)
        if n_fields not in (1, 2):
            raise ValueError(f"n_fields must be 1 or 2, got {n_fields}")
        if backend not in ("numba", "numpy"):
            raise ValueError(f"backend must be 'numba' or 'numpy', got {backend!r}")
        self.grid, self.fdtd, self.c, self.backend = grid, fdtd, c, backend
        self.walls = walls if walls is not None else WallNodes.none(grid)
        self.coef = make_coefficients(grid, fdtd, c)
        dtype = np.dtype(fdtd.dtype)
        self.dtype = dtype
        self.offset = dtype.type(1e-6 if fdtd.denormal_guard else 0.0)
        self.flush = dtype.type(_FLUSH if fdtd.denormal_guard else 0.0)
        nx, ny = grid.shape
        self.p = np.full((n_fields, nx, ny), self.offset, dtype=dtype)
        self.qx = np.zeros((n_fields, nx + 1, ny), dtype=dtype)
        self.qy = np.zeros((n_fields, nx, ny + 1), dtype=dtype)
        self.psx = np.zeros((n_fields, nx, ny), dtype=dtype)
        self._wx = _csr_rows(self.walls.wx)
        self._wy = _csr_rows(self.walls.wy)
        imp = self.walls.beta > 0
        self._imp_ptr, self._imp_col = _csr_rows(imp)
        self._imp_beta = self.walls.beta[imp].astype(dtype)
        self._imp_buf = np.zeros(self._imp_beta.size, dtype=dtype)

    @property
    def pressure(self) -> NDArray[Any]:
        """Pressure fields without the storage offset, (n_fields, nx, ny)."""
        return np.asarray(self.p - self.offset)

    def run(self, src_i: IntArray, src_j: IntArray, src_w: FloatArray, src_g: FloatArray,
            rx_i: IntArray, rx_j: IntArray, rx_w: FloatArray) -> FloatArray:
        """Advance ``len(src_g)`` steps; step n adds ``w * g[n]`` at the source nodes and
        records the bilinear receiver pressure after it. Returns (n, n_fields)."""
        n = int(np.asarray(src_g).shape[0])
        out = np.zeros((n, self.p.shape[0]))
        args = (np.ascontiguousarray(src_i, dtype=np.int64),
                np.ascontiguousarray(src_j, dtype=np.int64),
                np.ascontiguousarray(src_w, dtype=np.float64),
                np.ascontiguousarray(src_g, dtype=np.float64),
                np.ascontiguousarray(rx_i, dtype=np.int64),
                np.ascontiguousarray(rx_j, dtype=np.int64),
                np.ascontiguousarray(rx_w, dtype=np.float64), out)
        c = self.coef
        common = (self.p, self.qx, self.qy, self.psx, c.aqx, c.bqx, c.aqy, c.bqy,
                  c.apx, c.bpx, c.apy, c.bpy, self.dtype.type(c.kp), self.grid.pml_cells)
        if self.backend == "numba":
            import numba

            threads = numba.get_num_threads()
            if self.p.size < _SMALL_GRID_CELLS:  # a thread barrier per step costs more
                numba.set_num_threads(1)
            try:
                _k._run_steps(*common, *self._wx, *self._wy, self._imp_ptr, self._imp_col,
                              self._imp_beta, self._imp_buf, self.offset, self.flush, *args,
                              _n_chunks(self.grid.shape[0]))
            finally:
                numba.set_num_threads(threads)
        else:
            beta = self.walls.beta.astype(self.dtype)
            _k._run_steps_numpy(*common, self.walls.wx, self.walls.wy, beta > 0, beta,
                                self.offset, self.flush, *args)
        return out

    def run_static(self, src_xy: FloatArray, rx_xy: FloatArray, g: FloatArray) -> FloatArray:
        """:meth:`run` with a static source and receiver (points (2,))."""
        n = len(g)
        si, sj, sw = bilinear_stencil(np.asarray(src_xy)[None], self.grid)
        ri, rj, rw = bilinear_stencil(np.asarray(rx_xy)[None], self.grid)
        rep = (n, 1)
        return self.run(np.tile(si, rep), np.tile(sj, rep), np.tile(sw, rep), np.asarray(g),
                        np.tile(ri, rep), np.tile(rj, rep), np.tile(rw, rep))

    def state_arrays(self) -> dict[str, NDArray[Any]]:
        """Copy of the fields for a checkpoint."""
        return {"p": self.p.copy(), "qx": self.qx.copy(), "qy": self.qy.copy(),
                "psx": self.psx.copy()}

    def load_state(self, arrays: dict[str, NDArray[Any]]) -> None:
        """Restore fields written by :meth:`state_arrays`; ``ValueError`` on a mismatch."""
        for name in ("p", "qx", "qy", "psx"):
            cur = getattr(self, name)
            new = np.asarray(arrays[name])
            if new.shape != cur.shape or new.dtype != cur.dtype:
                raise ValueError(f"checkpoint field {name!r} has shape {new.shape} {new.dtype}, "
                                 f"expected {cur.shape} {cur.dtype}")
            cur[...] = new


def _n_chunks(nx: int) -> int:
    import numba

    return max(1, min(nx // 2, 4 * numba.get_num_threads()))


def leapfrog_energy(p_prev: NDArray[Any], p: NDArray[Any], qx: NDArray[Any], qy: NDArray[Any],
                    density_kg_m3: float, c: float, grid_step_m: float) -> float:
    """Discrete energy per unit depth (J/m) exactly conserved by eqs. 9-11 in a rigid box.

    ``E^(n+1/2) = dx^2 [ sum p^n p^(n+1) / (2 rho c^2) + rho / 2 sum |q^(n+1/2)|^2 ]``
    (pressures without the storage offset). Positive definite for Courant <= 1 / sqrt(2).
    """
    pp = np.sum(np.asarray(p_prev, np.float64) * np.asarray(p, np.float64))
    qq = np.sum(np.asarray(qx, np.float64) ** 2) + np.sum(np.asarray(qy, np.float64) ** 2)
    e = pp / (2 * density_kg_m3 * c * c) + density_kg_m3 / 2 * qq
    return float(e * grid_step_m**2)


# ---- the injected source signal -----------------------------------------------------------
def source_filter(freq_hz: ArrayLike, sonar: SonarConfig, fdtd: FdtdConfig) -> NDArray[Any]:
    """Complex gain from the transmitted signal to the per-step pressure increment.

    The injected volume velocity (per unit depth) is ``Q = sqrt(8 pi k_c) s / (i w rho)``,
    ``k_c = 2 pi f_c / c``, so that the field is ``sqrt(8 pi k_c)`` times the 2-D Green's
    function ``G = (-i/4) H0^(2)(k r)`` convolved with ``s`` -- the convention of the
    image-source engine's ``2d`` spreading (far field ``s(t - r/c)`` half-integrated, with
    ``1/sqrt(r)`` decay and unit gain at the carrier). The per-step increment is
    ``rho c^2 dt / dx^2 * Q``; raised-cosine tapers 0 -> 0.1 f_c (high-pass) and
    0.8 f_max -> f_max (low-pass, band limit of the grid) multiply it. Numpy FFT sign
    convention (``e^{+i w t}``).
    """
    c = fdtd.speed(sonar)
    _, fmax = injected_band(sonar, fdtd)
    fs = np.asarray(freq_hz, dtype=np.float64)
    f = np.abs(fs)
    f_lo = 0.1 * sonar.carrier_hz
    hp = np.where(f >= f_lo, 1.0, 0.5 - 0.5 * np.cos(np.pi * np.clip(f / f_lo, 0, 1)))
    x = np.clip((f - 0.8 * fmax) / (0.2 * fmax), 0, 1)
    lp = 0.5 + 0.5 * np.cos(np.pi * x)
    k_c = 2 * np.pi * sonar.carrier_hz / c
    w = 2 * np.pi * np.where(fs == 0, 1.0, fs)
    gain = c * c * fdtd.time_step_s / fdtd.grid_step_m**2 * math.sqrt(8 * np.pi * k_c)
    return np.asarray(np.where(fs == 0, 0.0, gain * hp * lp / (1j * w)))


@lru_cache(maxsize=8)
def _source_table(sonar: SonarConfig, fdtd: FdtdConfig, filtered: bool) -> FloatArray:
    period = tx_period(sonar)
    p = period.size
    spec = np.fft.rfft(period)
    if filtered:
        spec = spec * source_filter(np.fft.rfftfreq(p, 1 / sonar.fs_hz), sonar, fdtd)
    fine = p * _TABLE_UPSAMPLE
    padded = np.zeros(fine // 2 + 1, dtype=complex)
    padded[: spec.size] = spec
    if p % 2 == 0:
        padded[p // 2] *= 0.5
    table = np.fft.irfft(padded, n=fine) * _TABLE_UPSAMPLE
    table = np.concatenate([table[-2:], table, table[:3]])
    table.setflags(write=False)
    return table


def source_signal(t_s: ArrayLike, sonar: SonarConfig, fdtd: FdtdConfig,
                  filtered: bool = True) -> FloatArray:
    """Injected per-step pressure increment g(t) (``filtered=False``: the plain band-limited
    transmitted signal, equal to ``mapping.signal.transmitted_at``).

    Periodic band-limited interpolation (cubic Lagrange on a 32x table) of the filtered
    period spectrum.
    """
    table = _source_table(sonar, fdtd, filtered)
    fine = sonar.period_samples * _TABLE_UPSAMPLE
    u = np.mod(np.asarray(t_s, dtype=np.float64) * (sonar.fs_hz * _TABLE_UPSAMPLE), fine)
    i = np.floor(u)
    f = u - i
    k = i.astype(np.int64) + 2
    wm1 = -f * (f - 1.0) * (f - 2.0) / 6.0
    w0 = (f + 1.0) * (f - 1.0) * (f - 2.0) / 2.0
    w1 = -(f + 1.0) * f * (f - 2.0) / 2.0
    w2 = (f + 1.0) * f * (f - 1.0) / 6.0
    return np.asarray(wm1 * table[k - 1] + w0 * table[k] + w1 * table[k + 1] + w2 * table[k + 2])


def resample_to_rate(series: FloatArray, t_first_s: float, step_s: float, fs_hz: float,
                     first_sample: int, n_samples: int) -> FloatArray:
    """Band-limited resampling of a step series (sample m at ``t_first_s + m step_s``) to the
    sonar samples ``first_sample ..`` at ``k / fs_hz``; Kaiser-windowed sinc, cut-off fs / 2.

    Needs the series to cover ``_RESAMPLE_HALF_WIDTH`` steps beyond each output time.
    """
    series = np.asarray(series, dtype=np.float64)
    t = (first_sample + np.arange(n_samples)) / fs_hz
    pos = (t - t_first_s) / step_s
    base = np.floor(pos).astype(np.int64)
    h = _RESAMPLE_HALF_WIDTH
    if n_samples and (base[0] - h + 1 < 0 or base[-1] + h >= series.size):
        raise ValueError("series does not cover the requested samples plus the filter length")
    out = np.zeros(n_samples)
    fc = min(0.5 * fs_hz, 0.5 / step_s)
    beta = 8.0
    norm = np.i0(beta)
    for m in range(-h + 1, h + 1):
        tau = (pos - (base + m)) * step_s
        x = np.clip(tau / (h * step_s), -1, 1)
        win = np.i0(beta * np.sqrt(1 - x * x)) / norm
        out += series[base + m] * (2 * fc * step_s) * np.sinc(2 * fc * tau) * win
    return out


# ---- the moving-sonar simulation ----------------------------------------------------------
def path_position(trajectory: TrajectoryLike, t_s: ArrayLike) -> FloatArray:
    """Position (n, 2) at ``t_s``; before 0 and after the end the motion continues straight
    at the end velocity (steady state of the endless transmission)."""
    t = np.asarray(t_s, dtype=np.float64)
    end = float(trajectory.duration_s)
    tc = np.clip(t, 0.0, end)
    pos = np.asarray(trajectory.position(tc), dtype=np.float64).reshape(-1, 2)
    before, after = t < 0, t > end
    if before.any():
        v0 = np.asarray(trajectory.velocity(np.array([0.0])), np.float64).reshape(2)
        pos[before] += (t[before] - 0.0)[:, None] * v0
    if after.any():
        v1 = np.asarray(trajectory.velocity(np.array([end])), np.float64).reshape(2)
        pos[after] += (t[after] - end)[:, None] * v1
    return pos


@dataclass(frozen=True)
class FdtdSetup:
    """Everything fixed before the first step of a moving-sonar run."""

    sonar: SonarConfig
    fdtd: FdtdConfig
    grid: FdtdGrid
    walls: WallNodes
    c: float
    n_blocks: int
    t_start_s: float
    n_steps: int
    report: FdtdReport
    segments_m: FloatArray
    impedance_pa_s_m: FloatArray
    trajectory: TrajectoryLike
    first_block: int = 0


@dataclass
class FdtdState:
    """Mutable progress of a run: the solver fields, steps done and the received series
    (one value per step: field with walls minus field without, at the receiver)."""

    solver: FdtdSolver
    step: int = 0
    received: FloatArray = field(default_factory=lambda: np.zeros(0))

    def to_arrays(self) -> dict[str, NDArray[Any]]:
        """Arrays of a checkpoint."""
        arrays = self.solver.state_arrays()
        arrays["step"] = np.array(self.step)
        arrays["received"] = self.received[: self.step].copy()
        return arrays


@dataclass(frozen=True)
class FdtdProgress:
    """Yielded after each chunk of steps."""

    steps_done: int
    steps_total: int
    state: FdtdState


def setup_fdtd(segments_m: FloatArray, impedance_pa_s_m: FloatArray,
               trajectory: TrajectoryLike, sonar: SonarConfig, fdtd: FdtdConfig,
               n_blocks: int | None = None, first_block: int = 0) -> FdtdSetup:
    """Fit the grid, rasterize the walls and plan the steps of a moving-sonar run.

    Parameters
    ----------
    segments_m : ndarray, shape (W, 2, 2)
        Wall segments [[x0, y0], [x1, y1]] in metres.
    impedance_pa_s_m : ndarray, shape (W,)
        Normal acoustic impedance of each wall (inf = rigid, Table 2).
    trajectory : TrajectoryLike
        Sonar path (source and receiver co-located).
    sonar, fdtd : SonarConfig, FdtdConfig
    n_blocks : int or None
        Blocks to simulate; None: as many whole blocks as the path lasts (at least 1).
    first_block : int
        Index of the first block (block k starts at ``k * block_s``); the warm-up precedes it.

    Raises
    ------
    ValueError
        Courant number above 1 / sqrt(2), bad shapes, n_blocks < 1.

    Warns
    -----
    UserWarning
        Fewer than ``fdtd.warn_points_per_wavelength`` grid points per wavelength at the
        injected band edge.
    """
    c = fdtd.speed(sonar)
    courant = check_courant(fdtd, c)
    seg = np.asarray(segments_m, dtype=np.float64).reshape(-1, 2, 2)
    z = np.broadcast_to(np.asarray(impedance_pa_s_m, dtype=np.float64), (seg.shape[0],)).copy()
    if n_blocks is None:
        n_blocks = max(1, int(math.floor(float(trajectory.duration_s) / sonar.block_s + 1e-9)))
    if n_blocks < 1:
        raise ValueError(f"n_blocks must be >= 1, got {n_blocks}")
    if first_block < 0:
        raise ValueError(f"first_block must be >= 0, got {first_block}")
    t0 = first_block * sonar.block_s
    t_end = (first_block + n_blocks) * sonar.block_s
    path = path_position(trajectory, np.linspace(t0, t_end, 512))
    points = np.concatenate([seg.reshape(-1, 2), path]) if seg.size else path
    grid = fit_grid(points, fdtd)
    nx, ny = grid.shape
    diag = math.hypot(nx, ny) * fdtd.grid_step_m
    warmup = 2 * diag / c if fdtd.warmup_s is None else fdtd.warmup_s
    dt = fdtd.time_step_s
    warmup_steps = int(math.ceil(warmup / dt))
    t_start = t0 - warmup_steps * dt
    n_steps = warmup_steps + int(math.ceil((t_end - t0) / dt)) + _RESAMPLE_HALF_WIDTH + 2
    pre = path_position(trajectory, np.array([t_start]))
    grid_all = fit_grid(np.concatenate([points, pre]), fdtd)
    walls = wall_nodes(seg, z, grid_all, fdtd, c)
    report = _report(grid_all, sonar, fdtd, c, courant, n_steps, warmup_steps)
    if report.points_per_wavelength_injected_edge < fdtd.warn_points_per_wavelength:
        warnings.warn(
            f"FDTD grid: {report.points_per_wavelength_injected_edge:.1f} points per wavelength "
            f"at the injected band edge {report.injected_max_hz / 1e3:.3g} kHz (< "
            f"{fdtd.warn_points_per_wavelength:g}); group-velocity error there "
            f"{report.group_velocity_error_injected_edge[0] * 100:+.1f} % (axis)",
            stacklevel=2,
        )
    return FdtdSetup(sonar, fdtd, grid_all, walls, c, n_blocks, t_start, n_steps, report,
                     seg, z, trajectory, first_block)


def _report(grid: FdtdGrid, sonar: SonarConfig, fdtd: FdtdConfig, c: float, courant: float,
            n_steps: int, warmup_steps: int) -> FdtdReport:
    edge, fmax = injected_band(sonar, fdtd)
    dx, dt = fdtd.grid_step_m, fdtd.time_step_s

    def one(f: float, a: float) -> float:
        try:
            return numerical_group_velocity(f, a, dx, dt, c) / c - 1
        except ValueError:  # above the grid's cut-off: the grid does not carry it at all
            return float("nan")

    def err(f: float) -> tuple[float, float]:
        return one(f, 0.0), one(f, math.pi / 4)

    nx, ny = grid.shape
    nbytes = 2 * (4 * nx * ny + nx + ny) * np.dtype(fdtd.dtype).itemsize
    return FdtdReport(
        shape=grid.shape, origin_m=grid.origin_m, grid_step_m=dx, time_step_s=dt,
        courant=courant, signal_band_edge_hz=edge, injected_max_hz=fmax,
        points_per_wavelength_signal_edge=c / (edge * dx),
        points_per_wavelength_injected_edge=c / (fmax * dx),
        group_velocity_error_carrier=err(sonar.carrier_hz),
        group_velocity_error_injected_edge=err(fmax),
        n_steps=n_steps, warmup_steps=warmup_steps, field_bytes=nbytes,
    )


def new_state(setup: FdtdSetup, backend: str = "numba") -> FdtdState:
    """Zero fields (quiet before the warm-up starts)."""
    solver = FdtdSolver(setup.grid, setup.fdtd, setup.c, setup.walls, 2, backend)
    return FdtdState(solver=solver, step=0, received=np.zeros(setup.n_steps))


def restore_state(setup: FdtdSetup, arrays: dict[str, NDArray[Any]],
                  backend: str = "numba") -> FdtdState:
    """State from checkpoint arrays (see :meth:`FdtdState.to_arrays`)."""
    state = new_state(setup, backend)
    state.solver.load_state(arrays)
    step = int(arrays["step"])
    if not 0 <= step <= setup.n_steps:
        raise ValueError(f"checkpoint step {step} outside 0..{setup.n_steps}")
    state.step = step
    state.received[:step] = np.asarray(arrays["received"])[:step]
    return state


def advance(setup: FdtdSetup, state: FdtdState, n: int) -> None:
    """Advance ``state`` by up to ``n`` steps of the run (moving source and receiver)."""
    n = min(n, setup.n_steps - state.step)
    if n <= 0:
        return
    dt = setup.fdtd.time_step_s
    steps = state.step + np.arange(n)
    t_mid = setup.t_start_s + (steps + 0.5) * dt
    t_rx = setup.t_start_s + (steps + 1.0) * dt
    si, sj, sw = bilinear_stencil(path_position(setup.trajectory, t_mid), setup.grid)
    ri, rj, rw = bilinear_stencil(path_position(setup.trajectory, t_rx), setup.grid)
    g = source_signal(t_mid, setup.sonar, setup.fdtd)
    out = state.solver.run(si, sj, sw, g, ri, rj, rw)
    state.received[state.step: state.step + n] = out[:, 0] - out[:, 1]
    state.step += n


def block_samples(setup: FdtdSetup, state: FdtdState, k: int) -> FloatArray:
    """Received samples of block ``k`` (absolute index) at the sonar rate; needs
    :func:`steps_needed` steps done."""
    B = setup.sonar.block_samples
    t_first = setup.t_start_s + setup.fdtd.time_step_s  # received[m] is at t_start + (m+1) dt
    return resample_to_rate(state.received[: state.step], t_first, setup.fdtd.time_step_s,
                            setup.sonar.fs_hz, k * B, B)


def steps_needed(setup: FdtdSetup, k: int) -> int:
    """Steps after which block ``k`` can be resampled."""
    t_last = ((k + 1) * setup.sonar.block_samples - 1) / setup.sonar.fs_hz
    m = int(math.floor((t_last - setup.t_start_s) / setup.fdtd.time_step_s))
    return min(setup.n_steps, m + _RESAMPLE_HALF_WIDTH + 1)


def iter_fdtd(setup: FdtdSetup, state: FdtdState | None = None,
              chunk_steps: int = 2000) -> Iterator[FdtdProgress]:
    """Run the remaining steps of ``setup`` in chunks, yielding progress after each.

    The caller may stop at any yield and checkpoint ``progress.state.to_arrays()``; a later
    call with the restored state continues exactly where it stopped.
    """
    if chunk_steps < 1:
        raise ValueError(f"chunk_steps must be >= 1, got {chunk_steps}")
    state = new_state(setup) if state is None else state
    while state.step < setup.n_steps:
        advance(setup, state, chunk_steps)
        yield FdtdProgress(state.step, setup.n_steps, state)


def _empty_paths() -> PathTable:
    e = np.zeros(0)
    return PathTable(order=np.zeros(0, np.int64), walls=(), delay_s=e, doppler_factor=e,
                     angle_to_velocity_rad=e, reflection=e, amplitude=e)


def sim_block(setup: FdtdSetup, state: FdtdState, k: int) -> SimBlock:
    """Block ``k`` (absolute index) as a :class:`~mapping.simulate.base.SimBlock`; the
    path table is empty (the FDTD does not separate echo paths)."""
    if state.step < steps_needed(setup, k):
        raise ValueError(f"block {k} needs {steps_needed(setup, k)} steps, {state.step} done")
    traj = setup.trajectory
    t_mid = np.array([(k + 0.5) * setup.sonar.block_s])
    return SimBlock(
        index=k, samples=block_samples(setup, state, k), t_s=k * setup.sonar.block_s,
        pose=np.asarray(traj.pose(t_mid), dtype=np.float64).reshape(3),
        speed_m_s=float(np.asarray(traj.speed_m_s(t_mid)).ravel()[0]),
        yaw_rate_rad_s=float(np.asarray(traj.yaw_rate_rad_s(t_mid)).ravel()[0]),
        paths=_empty_paths(), meta={"engine": "fdtd"},
    )


def finished_blocks(setup: FdtdSetup, state: FdtdState) -> list[SimBlock]:
    """The blocks of a completed run (``state.step == setup.n_steps``)."""
    if state.step < setup.n_steps:
        raise ValueError(f"run incomplete: {state.step} of {setup.n_steps} steps done")
    ks = range(setup.first_block, setup.first_block + setup.n_blocks)
    return [sim_block(setup, state, k) for k in ks]


def iter_fdtd_blocks(scene: SceneLike, trajectory: TrajectoryLike, config: SonarConfig,
                     n_blocks: int, engine: FdtdConfig, rng: np.random.Generator | None = None,
                     first_block: int = 0, chunk_steps: int = 2000) -> Iterator[SimBlock]:
    """The FDTD engine behind :func:`mapping.simulate.iter_blocks`: blocks in order, each
    yielded as soon as the steps covering it are done (``rng`` unused: deterministic)."""
    setup = setup_for_scene(scene, trajectory, config, engine, n_blocks, first_block)
    state = new_state(setup)
    k = first_block
    for progress in iter_fdtd(setup, state, chunk_steps):
        while k < first_block + n_blocks and progress.steps_done >= steps_needed(setup, k):
            yield sim_block(setup, state, k)
            k += 1


def scene_walls(scene: SceneLike, density_kg_m3: float, c: float) -> tuple[FloatArray, FloatArray]:
    """Segments (W, 2, 2) and normal impedances (W,) of a scene.

    The impedance follows from the scene's normal-incidence reflection coefficient R,
    ``Z = rho c (1 + R) / (1 - R)`` (R = 1: rigid, Z = inf), so both engines agree.
    """
    seg = np.asarray(scene.segments(), dtype=np.float64).reshape(-1, 2, 2)
    r = np.asarray(scene.reflection_coefficients(), dtype=np.float64).reshape(-1)
    if r.shape[0] != seg.shape[0] or np.any(~((r > -1) & (r <= 1))):
        raise ValueError("scene reflection coefficients must be one per wall, in (-1, 1]")
    with np.errstate(divide="ignore"):
        z = np.where(r >= 1, np.inf, density_kg_m3 * c * (1 + r) / np.maximum(1 - r, 1e-300))
    return seg, z


def setup_for_scene(scene: SceneLike, trajectory: TrajectoryLike, sonar: SonarConfig,
                    fdtd: FdtdConfig, n_blocks: int | None = None,
                    first_block: int = 0) -> FdtdSetup:
    """:func:`setup_fdtd` for a :class:`~mapping.scene.Scene`-like object."""
    seg, z = scene_walls(scene, fdtd.density_kg_m3, fdtd.speed(sonar))
    return setup_fdtd(seg, z, trajectory, sonar, fdtd, n_blocks, first_block)


def run_meta(setup: FdtdSetup) -> dict[str, Any]:
    """Run-file ``meta`` of an FDTD run (engine, config, set-up report)."""
    return {"engine": "fdtd", "engine_config": setup.fdtd.to_dict(),
            "fdtd_report": asdict(setup.report), "direct_path": False,
            "path": getattr(setup.trajectory, "name", None)}


def simulate_fdtd(scene: SceneLike, trajectory: TrajectoryLike, sonar: SonarConfig,
                  fdtd: FdtdConfig | None = None, n_blocks: int | None = None) -> Run:
    """Simulate a whole run with the FDTD engine (no progress, no checkpoints).

    Returns the same :class:`~mapping.runfile.Run` as the image-source engine.
    """
    setup = setup_for_scene(scene, trajectory, sonar, fdtd or FdtdConfig(), n_blocks)
    state = new_state(setup)
    for _ in iter_fdtd(setup, state):
        pass
    return assemble_run(finished_blocks(setup, state), sonar, scene.to_json(), run_meta(setup))


def setup_fingerprint(setup: FdtdSetup) -> str:
    """Hash of everything that fixes the step sequence (a checkpoint resumes only onto an
    identical set-up)."""
    import hashlib
    import json

    key = {
        "sonar": setup.sonar.to_json(), "fdtd": setup.fdtd.to_dict(), "shape": setup.grid.shape,
        "origin": setup.grid.origin_m, "n_steps": setup.n_steps, "t_start": setup.t_start_s,
        "segments": setup.segments_m.round(9).tolist(),
        "impedance": [str(z) for z in setup.impedance_pa_s_m],
        "path": path_position(setup.trajectory, np.linspace(setup.t_start_s, setup.t_start_s
                                                            + setup.n_steps
                                                            * setup.fdtd.time_step_s,
                                                            64)).round(9).tolist(),
        "first_block": setup.first_block,
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def default_chunk_steps(setup: FdtdSetup) -> int:
    """Steps per progress report: about 3e8 cell updates (a second or two)."""
    nx, ny = setup.grid.shape
    return int(max(20, min(5000, 3e8 // (nx * ny))))

