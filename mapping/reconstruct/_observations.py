"""Parameters and observations of the inverse reconstruction (:mod:`mapping.reconstruct`).

:class:`InverseParams` bundles the solver's parameters. The observations are each used
block's heat map after the per-block floor removal of :mod:`mapping.grid`, max-pooled over
range bins of ``bin_m`` up to ``radius_m`` (:func:`pool_heatmap`), with the block's Doppler
point-spread parameter (:func:`doppler_kappa`), gathered into :class:`Observations` by
:func:`observations_from_heatmaps`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.grid import GridParams, remove_floor
from mapping.heatmap import HeatMap
from mapping.signal import SonarConfig

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class InverseParams:
    """Parameters of the inverse reconstruction.

    Parameters
    ----------
    orientations : int
        Number O of normal-axis orientations per cell (1 = isotropic point reflectors).
    bin_m : float or None
        Range bin of the observations in metres (None: the map resolution).
    lam_rel : float
        l1 weight relative to ``max(A^T y)``.
    iterations : int
        FISTA iterations.
    active_fraction : float
        Cells whose back-projection is below this fraction of its 99th percentile are fixed at 0.
    free_fraction, free_margin_m : float
        Free-space constraint: in each block, the first range bin whose strongest row reaches
        ``free_fraction`` of the block's maximum is the nearest reflector (the nearest point of a
        specular wall is its perpendicular foot, which echoes; corners echo from anywhere); cells
        closer to the pose than that range minus ``free_margin_m`` are fixed at 0. Set
        ``free_fraction = 0`` to disable. Within ``free_full_m`` of the pose every orientation is
        ruled out (a full free disc); beyond it only the elements that would have echoed to
        the pose (their normal points at it), because a non-specular wall end closer than
        the nearest echo gives no echo of its own.
    reweight_rounds, reweight_eps, reweight_gain : int, float, float
        Reweighted l1 (Candes, Wakin & Boyd 2008): after each solve the weight of unknown i
        becomes ``gain * eps / (x_i / s + eps)`` with ``s`` the 99th percentile of x > 0, and
        the problem is solved again from the last solution. Sparser maps, less bias on strong
        cells.
    occlusion_rounds, occluder_fraction, occlusion_margin_m : int, float, float
        Occlusion: after a solve, cells above ``occluder_fraction`` of the 99th percentile of
        the map are taken as walls; the operator is rebuilt so that a cell farther than the
        first such wall along its bearing (plus ``occlusion_margin_m``) is invisible from that
        pose, and the problem is solved again. Multiple-reflection echoes, which the
        back-projection places behind the walls, then have nothing to explain them.
    prune_fraction : float
        After solving, cells of G below this fraction of its 99th percentile (of G > 0) are
        set to 0: the solver's residual speckle (support pruning). Off by default: it lowers
        the ghost energy a little but raises the 99th percentile of the remaining positive
        cells that the quality thresholds scale with, which costs recall (README numbers).
    doppler_spread : bool
        Model the Doppler bank's angular point spread ``|sinc(kappa dcos)|`` (see
        :func:`doppler_kappa`) in the operator. Off by default: on the image-source runs it
        made the operator 5x denser and did not improve precision/recall (README numbers).
    """

    orientations: int = 16
    bin_m: float | None = None
    lam_rel: float = 0.01
    iterations: int = 200
    active_fraction: float = 0.15
    free_fraction: float = 0.3
    free_margin_m: float = 0.1
    free_full_m: float = 1.0
    doppler_spread: bool = False
    prune_fraction: float = 0.0
    reweight_rounds: int = 0
    occlusion_rounds: int = 0
    occluder_fraction: float = 0.5
    occlusion_margin_m: float = 0.2
    reweight_eps: float = 0.1
    reweight_gain: float = 2.0

    def __post_init__(self) -> None:
        if not 1 <= self.orientations <= 360:
            raise ValueError(f"orientations must be in 1..360, got {self.orientations}")
        if self.bin_m is not None and not (math.isfinite(self.bin_m) and self.bin_m > 0):
            raise ValueError(f"bin_m must be > 0 or None, got {self.bin_m}")
        if not 0 <= self.lam_rel < 1:
            raise ValueError(f"lam_rel must be in [0, 1), got {self.lam_rel}")
        if not 1 <= self.iterations <= 100_000:
            raise ValueError(f"iterations must be in 1..100000, got {self.iterations}")
        if not 0 <= self.free_fraction <= 1:
            raise ValueError(f"free_fraction must be in [0, 1], got {self.free_fraction}")
        if not self.free_margin_m >= 0:
            raise ValueError(f"free_margin_m must be >= 0, got {self.free_margin_m}")
        if not 0 <= self.prune_fraction < 1:
            raise ValueError(f"prune_fraction must be in [0, 1), got {self.prune_fraction}")
        if not 0 <= self.active_fraction < 1:
            raise ValueError(f"active_fraction must be in [0, 1), got {self.active_fraction}")

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON parameters."""
        return asdict(self)


@dataclass(frozen=True)
class Observations:
    """Range-pooled heat maps of the used blocks: ``Y[k, n_theta, n_r]`` at ``poses[k]``.

    ``kappa[k]`` is the Doppler point-spread parameter of block k (0: no spread modelled).
    """

    Y: FloatArray
    poses: FloatArray
    bin_m: float
    kappa: FloatArray

    @property
    def n_dirs(self) -> int:
        """Rows N + 1 of each heat map."""
        return int(self.Y.shape[1])


def pool_heatmap(heatmap: HeatMap, bin_m: float, radius_m: float, floor: str) -> FloatArray:
    """Floor-removed heat map max-pooled into range bins ``round(r / bin_m)`` up to radius."""
    H = remove_floor(heatmap.H, floor)
    n_bins = int(math.floor(radius_m / bin_m + 0.5)) + 1
    b = np.floor(heatmap.ranges_m / bin_m + 0.5).astype(np.int64)
    keep = b < n_bins
    out = np.zeros((H.shape[0], n_bins))
    np.maximum.at(out.T, b[keep], H[:, keep].T)
    return out


def doppler_kappa(speed_m_s: float, config: SonarConfig) -> float:
    """Carrier cycles of delay drift per unit of cos(angle) mismatch over a block.

    A row of the Doppler bank that misses the echo's ``cos(theta)`` by ``dcos`` leaves a
    residual compression ``2 v dcos / c``; over the block (``T = M P / fs``) the delay drifts
    by ``2 v T dcos / c`` seconds, i.e. ``kappa * dcos`` carrier cycles with
    ``kappa = 2 |v| T f_c / c``, and the coherent sum falls like ``|sinc(kappa dcos)|``
    (first zero at ``dcos = 1 / kappa``: 0.17 for Table 1 at 0.1 m/s). This is the model's
    angular point-spread function; larger M narrows it (paper Fig. 7).
    """
    return 2.0 * abs(speed_m_s) * config.block_s * config.carrier_hz / config.sound_speed_m_s


def observations_from_heatmaps(
    heatmaps: Iterable[HeatMap | None], poses: FloatArray, grid: GridParams,
    params: InverseParams, config: SonarConfig | None = None,
) -> tuple[Observations, dict[str, int]]:
    """Pool every tracked, observable block's heat map; counts as in :func:`grid.accumulate`.

    With ``config`` and ``params.doppler_spread`` the Doppler point-spread parameter of each
    block comes from :func:`doppler_kappa` at the heat map's speed; otherwise none is modelled.
    """
    poses = np.asarray(poses, dtype=np.float64)
    bin_m = params.bin_m or grid.resolution_m
    Y, used, kappa = [], [], []
    counts = {"blocks_used": 0, "blocks_untracked": 0, "blocks_unobservable": 0}
    for k, hm in enumerate(heatmaps):
        if hm is None or not np.all(np.isfinite(poses[k])):
            counts["blocks_untracked"] += 1
        elif grid.skip_unobservable and not hm.direction_observable:
            counts["blocks_unobservable"] += 1
        else:
            Y.append(pool_heatmap(hm, bin_m, grid.radius_m, grid.floor))
            used.append(k)
            use = config is not None and params.doppler_spread
            kappa.append(doppler_kappa(hm.speed_m_s, config) if use and config else 0.0)
            counts["blocks_used"] += 1
    n_dirs = Y[0].shape[0] if Y else 2
    n_bins = Y[0].shape[1] if Y else 1
    arr = np.array(Y) if Y else np.zeros((0, n_dirs, n_bins))
    return Observations(arr, poses[used].reshape(-1, 3), bin_m, np.array(kappa)), counts


def concat_observations(parts: list[Observations]) -> Observations:
    """Observations of several runs, in order."""
    parts = [p for p in parts if p.Y.shape[0] > 0]
    if not parts:
        raise ValueError("no observations to reconstruct from")
    return Observations(np.concatenate([p.Y for p in parts]),
                        np.concatenate([p.poses for p in parts]), parts[0].bin_m,
                        np.concatenate([p.kappa for p in parts]))
