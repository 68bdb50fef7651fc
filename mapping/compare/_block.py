"""Comparing the FDTD reference with the image-source engine (paper Sec. 3 against Sec. 2).

The two engines hear the same scene differently in two known ways, and this module holds the
computation that accounts for both:

1. **Grid dispersion and band.** Every FDTD echo has travelled its whole path through the
   grid, so it arrives late by the grid's dispersion along its own direction, and only the
   band the FDTD injected is present. :func:`render_paths` rebuilds an image-source block path
   by path from its path table (delay and Doppler factor at the block midpoint, amplitude,
   the 2-D signal period), band-limited by the FDTD's injection tapers (:func:`grid_band`)
   and, per path, with the phase ``exp(-i (k_num(f, phi) - k) L)`` of its length ``L`` and
   direction ``phi`` (:func:`dispersion_phase`). :func:`fdtd_length_m` predicts where the
   envelope of a multi-leg path lands (each leg at the grid's group velocity along it).
2. **Paths the image-source model leaves out.** Diffraction at the free end of a wall: sound
   goes from the source (possibly via specular reflections) to the wall end and from there
   (possibly via reflections) to the receiver. :func:`free_wall_ends` finds the ends,
   :func:`specular_path` finds a bistatic specular path with its validity and occlusion, and
   :func:`edge_diffraction_paths` lists the diffracted paths with their heat-map range and
   Doppler angle (Keller's geometrical theory of diffraction: the edge re-radiates in all
   directions, so any leg into and out of it is a path; only its geometry is computed
   here, not its amplitude).

Heat-map bookkeeping: :func:`heatmap_angle_rad` (the angle a path shows in the Doppler heat
map of eq. 1: ``cos theta = (D - 1) c / (2 v)``, the mean of the departure and arrival
cosines), :func:`local_maxima` and :func:`window_peak`.

:func:`compare_block` runs both engines on one block of a scene and returns the waveforms,
the rebuilt image-source block and the geometric truth of every path
(:class:`BlockComparison`); :func:`comparison_heatmaps` and :func:`residual_waveform` turn it
into heat maps. Everything else is pure numpy.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.compare._geometry import (
    GeometricEcho,
    specular_echo,
)
from mapping.compare._paths import (
    render_paths,
)
from mapping.heatmap import HeatMap, doppler_heatmap
from mapping.signal import SonarConfig
from mapping.simulate import PathTable, SceneLike, TrajectoryLike
from mapping.simulate.fdtd import FdtdConfig, FdtdReport
from mapping.simulate.ism import IsmConfig, iter_ism_blocks

FloatArray = NDArray[np.float64]




# ---- both engines on one block ------------------------------------------------------------
@dataclass(frozen=True)
class BlockComparison:
    """One block of a scene through both engines, and the geometric truth of its paths.

    Attributes
    ----------
    sonar, fdtd_config : SonarConfig, FdtdConfig
    block_index : int
    position_m, velocity_m_s : ndarray (2,)
        Sonar at the block midpoint.
    fdtd : ndarray (B,)
        The FDTD block (walls run minus free run).
    ism : ndarray (B,)
        The image-source engine's block (``spreading="2d"``).
    ism_band, ism_dispersed : ndarray (B,)
        The image-source block rebuilt from its path table (:func:`render_paths`),
        band-limited like the FDTD source, without and with the grid dispersion.
    paths : PathTable
        The image-source engine's paths at the midpoint.
    echoes : tuple of GeometricEcho or None
        Per path of ``paths``: its geometric truth (:func:`specular_echo`; None if the path
        does not exist at exactly the midpoint).
    report : FdtdReport
        The FDTD set-up report (points per wavelength, predicted dispersion).
    seconds : dict
        Wall-clock seconds of the two engines (for benchmarks; never asserted).
    """

    sonar: SonarConfig
    fdtd_config: FdtdConfig
    block_index: int
    position_m: FloatArray
    velocity_m_s: FloatArray
    fdtd: FloatArray
    ism: FloatArray
    ism_band: FloatArray
    ism_dispersed: FloatArray
    paths: PathTable
    echoes: tuple[GeometricEcho | None, ...]
    report: FdtdReport
    seconds: dict[str, float]

    @property
    def speed_m_s(self) -> float:
        """Speed at the block midpoint."""
        return float(np.hypot(*self.velocity_m_s))

    @property
    def heading_rad(self) -> float:
        """Direction of travel at the block midpoint."""
        return float(math.atan2(self.velocity_m_s[1], self.velocity_m_s[0]))


def compare_block(scene: SceneLike, trajectory: TrajectoryLike, sonar: SonarConfig,
                  fdtd: FdtdConfig, block_index: int,
                  ism_max_path_m: float | None = None) -> BlockComparison:
    """Run the FDTD and the image-source engine on block ``block_index`` and rebuild the
    image-source block as the grid would carry it.

    The image-source engine uses ``spreading="2d"`` (the FDTD's line source) and keeps
    paths up to ``ism_max_path_m`` (default ``c * fdtd.warmup_s``: what the FDTD has heard
    by the block's start). Each path is rendered with the dispersion along the direction of
    its geometric truth (:func:`specular_echo`), or, where that does not exist at exactly
    the midpoint, along ``heading + angle_to_velocity`` (the mirror image about the heading
    has the same dispersion only for headings along the grid axes or diagonals).

    Warns (``UserWarning``) like :func:`mapping.simulate.fdtd.setup_for_scene` on a grid with
    fewer than ``fdtd.warn_points_per_wavelength`` points per wavelength.
    """
    from mapping.simulate.fdtd import finished_blocks, iter_fdtd, new_state, setup_for_scene

    if fdtd.warmup_s is None and ism_max_path_m is None:
        raise ValueError("give fdtd.warmup_s or ism_max_path_m (which paths both engines hear)")
    c = fdtd.speed(sonar)
    max_path = c * float(fdtd.warmup_s or 0.0) if ism_max_path_m is None else ism_max_path_m
    k = int(block_index)
    t_mid = (k + 0.5) * sonar.block_s
    pos = np.asarray(trajectory.position(np.array([t_mid]))[0], dtype=np.float64)
    vel = np.asarray(trajectory.velocity(np.array([t_mid]))[0], dtype=np.float64)
    t0 = time.perf_counter()
    block = next(iter(iter_ism_blocks(scene, trajectory, sonar, 1,
                                      IsmConfig(spreading="2d", max_path_m=max_path),
                                      np.random.default_rng(0), first_block=k)))
    t1 = time.perf_counter()
    setup = setup_for_scene(scene, trajectory, sonar, fdtd, n_blocks=1, first_block=k)
    state = new_state(setup)
    for _ in iter_fdtd(setup, state):
        pass
    x_fdtd = np.asarray(finished_blocks(setup, state)[0].samples, dtype=np.float64)
    t2 = time.perf_counter()

    def position_at(t: float) -> FloatArray:
        return np.asarray(trajectory.position(np.array([t]))[0], dtype=np.float64)

    seg = scene.segments()
    paths = block.paths
    echoes = tuple(specular_echo(seg, w, position_at, vel, t_mid, sonar, fdtd)
                   for w in paths.walls)
    heading = float(math.atan2(vel[1], vel[0]))
    dirs = np.array([e.direction_rad if e is not None
                     else heading + float(paths.angle_to_velocity_rad[i])
                     for i, e in enumerate(echoes)])
    return BlockComparison(
        sonar=sonar, fdtd_config=fdtd, block_index=k, position_m=np.asarray(pos),
        velocity_m_s=np.asarray(vel), fdtd=x_fdtd,
        ism=np.asarray(block.samples, dtype=np.float64),
        ism_band=render_paths(paths, None, sonar, fdtd, k),
        ism_dispersed=render_paths(paths, dirs, sonar, fdtd, k),
        paths=paths, echoes=echoes, report=setup.report,
        seconds={"ism_block": t1 - t0, "fdtd_block": t2 - t1})


def correlation(a: ArrayLike, b: ArrayLike) -> float:
    """Normalised correlation ``<a, b> / (|a| |b|)`` of two waveforms."""
    x, y = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    den = float(np.linalg.norm(x) * np.linalg.norm(y))
    if x.shape != y.shape or not den > 0:
        raise ValueError("a and b must have the same shape and be non-zero")
    return float(np.dot(x.ravel(), y.ravel()) / den)


def residual_waveform(cmp: BlockComparison) -> FloatArray:
    """FDTD block minus the least-squares multiple of the dispersion-corrected image-source
    block: what the image-source model leaves unexplained (diffraction, amplitude errors)."""
    a = float(np.dot(cmp.fdtd, cmp.ism_dispersed) / np.dot(cmp.ism_dispersed, cmp.ism_dispersed))
    out: FloatArray = cmp.fdtd - a * cmp.ism_dispersed
    return out


def comparison_heatmaps(cmp: BlockComparison) -> dict[str, HeatMap]:
    """Doppler heat maps (paper eq. 1) of the FDTD block, the engine's image-source block, its
    dispersion-corrected rebuild and the residual waveform (:func:`residual_waveform`)."""
    v, s = cmp.speed_m_s, cmp.sonar
    return {"fdtd": doppler_heatmap(cmp.fdtd, v, s), "ism": doppler_heatmap(cmp.ism, v, s),
            "ism_dispersed": doppler_heatmap(cmp.ism_dispersed, v, s),
            "residual": doppler_heatmap(residual_waveform(cmp), v, s)}
