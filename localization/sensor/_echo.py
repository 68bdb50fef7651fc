"""The echo model: a physical sensor model on the map's walls; see :mod:`localization.sensor`.

At each pose the forward model (:func:`mapping.forward.echoes_batch`) lists the echoes the
map's walls give: specular points of the visible walls, inside corners and higher orders up
to ``SensorConfig.echo_order``, each with its range, Doppler cosine and level. The measured
block is reduced to its heat-map peaks (range, Doppler cosine). The likelihood (numba kernel
``_echo_kernel``) pairs the two with a Gaussian tolerance in range and cosine:

* every measured peak is explained by the nearest predicted echo or is clutter
  (``log(clutter + (1 - clutter) kappa)``: people, furniture, unmapped walls, orders above
  ``echo_order``);
* every predicted echo is heard or missed (``log(1 - p (1 - kappa))``, ``p`` at most
  ``p_detect``: occlusion, absorbing surfaces, weak echoes);
* every matched peak's level (its heat-map value relative to the block's strongest) is
  compared with the amplitude of the echoes that make it (summed where they fall within the
  tolerance), after the pose's common gain: ``SensorConfig.amplitude_sigma``. Range and
  cosine cannot tell an absorbing wall from a rigid one, nor a pose from its near-mirror in
  a room that is symmetric but for the walls' materials; the levels can (measured on the
  fresh14c workshop, R = 0.4 east wall: global starts locked onto the mirror 6.4 m away,
  with status converged, in 3 of 3 seeds without levels).

Folded left/right as eq. 1 is: only the Doppler cosine is compared, so a pose and its mirror
about the direction of travel score alike where the walls allow it. While the robot stands
still (no direction information) only ranges are compared. The score is returned in the
correlation's units, ``rho = 1 + ll / ECHO_NATS``, so the filter's tempering
(``beta * (rho - rho_best)``), floor and calibration apply unchanged: ``beta = ECHO_NATS``
uses the likelihood as it is.

Besides the likelihood the kernel reports, per pose, how much it explains: the share of
measured peaks explained and the share of expected echoes heard (:func:`explanation`). The
filter's honest status compares these at its estimate with what tracked runs show at the true
pose (:mod:`localization.estimate`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization.sensor import _kernels as _k
from localization.sensor._config import ECHO_NATS
from localization.sensor._measurement import Measurement
from localization.sensor._tables import SensorTables, end_weights, uniform_free_poses
from mapping.forward import EchoBatch, ForwardParams, echoes_batch, with_vertical

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Explanation:
    """How well poses explain one block (echo model).

    Attributes
    ----------
    log_likelihood : ndarray (n,)
        Untempered echo log-likelihood (nats).
    explained : ndarray (n,)
        Weighted share of the measured peaks a predicted echo explains, in [0, 1].
    heard : ndarray (n,)
        Detection-weighted share of the expected echoes that were heard, in [0, 1] (1 when
        the pose expects none).
    n_peaks : int
        Measured peaks of the block.
    """

    log_likelihood: FloatArray
    explained: FloatArray
    heard: FloatArray
    n_peaks: int


def cos_sigma(tables: SensorTables, measurement: Measurement) -> float:
    """Doppler-cosine tolerance of a block: ``max(cos_sigma_min, cos_sigma_beam * w)``, ``w =
    c / (2 |v| T f0)`` the width of eq. 1's Doppler beam at the block's speed."""
    cfg, sonar = tables.config, tables.sonar
    v = max(abs(measurement.speed_m_s), 1e-6)
    beam = sonar.sound_speed_m_s / (2.0 * v * sonar.block_s * sonar.carrier_hz)
    return float(min(max(cfg.cos_sigma_min, cfg.cos_sigma_beam * beam), 2.0))


def map_range_sigma(tables: SensorTables, batch: EchoBatch, parallel: bool = False
                    ) -> FloatArray | None:
    """The map's 1-sigma range uncertainty of each predicted echo (n, kmax), None for a map
    without one (ideal walls).

    Per wall the path bounces on, the normal offset ``o`` and the angle ``a`` of the fit
    (``WallMap.wall_sigma``) move the echo by ``o`` and by ``s a``, ``s`` the distance of
    the bounce point from the wall's middle (the fit turns about its centre of mass, which
    the middle stands in for); independent terms add in quadrature. numba kernel
    (``_kernels._map_sigma_kernel``; ``parallel``: over numba's threads, the same numbers); its
    numpy twin is in ``tests/localization/sensor/naive.py``.
    """
    ws = tables.wall_sigma
    if ws.shape[0] != tables.walls.n or not np.any(ws[:, :2] > 0):
        return None
    return _k.map_sigma_rows(np.asarray(tables.walls.segments_m, dtype=np.float64)
                             .reshape(-1, 2, 2), ws, batch.walls, batch.points_m, parallel)


def _terms(tables: SensorTables) -> _k._EchoTerms:
    """The kernel's constants. Levels are compared in 2-D rooms only: with floor / ceiling
    copies (``sonar_height_m`` given) a wall echo and its floor copy a few cm behind merge
    in the heat map by an amount the real heights set, and the comparison misled (measured
    on raw recordings of the l-room with heights: tracking 196 cm RMSE with levels, also
    with the copies left out of them, 0.8 cm without)."""
    cfg = tables.config
    sig_a = cfg.amplitude_sigma if cfg.sonar_height_m is None else 0.0
    return _k._EchoTerms(eps=cfg.clutter, p_max=cfg.p_detect, rel_lo=cfg.detect_lo,
                         rel_hi=cfg.detect_hi, r_min=cfg.min_range_m, r_max=cfg.max_range_m,
                         sig_a=sig_a)


#: Fewer poses than this are computed on one thread: starting numba's parallel region cost
#: 0.4-0.5 ms per call (measured: one pose 0.63 ms in parallel, four poses 0.19 ms serially),
#: and the filter asks for one to a few dozen poses several times per block (its estimate,
#: the symmetric twins, the rivals).
SERIAL_BELOW = 64


def predicted_echoes(tables: SensorTables, speed_m_s: float, poses: FloatArray,
                     parallel: bool | None = None) -> tuple[EchoBatch, FloatArray | None]:
    """The echoes the map's walls give at each pose (n, 3) moving at ``speed_m_s``: the
    forward model up to ``SensorConfig.echo_order`` within the sensor's range (free wall ends
    extended as :attr:`SensorTables.soft_ends` says), and each echo's range sigma from the
    map's own uncertainty (:func:`map_range_sigma`; None for ideal walls). The 2-D echoes
    only: the floor / ceiling copies are added by the caller (:func:`explanation`).
    ``parallel`` None spreads the poses over numba's threads from :data:`SERIAL_BELOW`
    poses on; False / True force one way (same results)."""
    cfg = tables.config
    params = ForwardParams(max_order=cfg.echo_order,
                           right_corner_tol_deg=cfg.right_corner_tol_deg,
                           max_range_m=cfg.max_range_m + 3 * cfg.range_sigma_m)
    if parallel is None:
        parallel = np.shape(poses)[0] >= SERIAL_BELOW
    b = echoes_batch(tables.soft_ends[0], poses, speed_m_s, tables.sonar, params,
                     parallel=parallel)
    if tables.wall_side is not None:
        b = faces_only(tables, b, poses, parallel)
    return b, map_range_sigma(tables, b, parallel)


#: How far behind a wall's line (m) a bounce may start and still count as from the heard
#: side: a corner's second bounce starts on the first wall's end, on the second wall's line.
FACE_TOL_M = 0.02


def faces_only(tables: SensorTables, batch: EchoBatch, poses: FloatArray,
               parallel: bool = False) -> EchoBatch:
    """``batch`` without the echoes that reach a wall from a side it was never heard from
    (``SensorTables.wall_side``): a fitted wall is the face the mapping runs heard, and what
    is behind it (the other face of a shelf stack, of a column) is unknown, so a pose there
    neither expects its echo nor may explain a peak with it. numba kernel
    (``_kernels._faces_kernel``; its numpy twin is in ``tests/localization/sensor/naive.py``);
    the kept echoes stay in range order, the rest of each row is padding."""
    side = tables.wall_side
    if side is None or batch.range_m.shape[1] == 0:
        return batch
    seg = np.asarray(tables.soft_ends[0].segments_m, dtype=np.float64).reshape(-1, 2, 2)
    keep = _k.face_rows(seg, side, np.asarray(poses, dtype=np.float64), batch.count,
                        batch.walls, batch.points_m, FACE_TOL_M, parallel)
    if np.array_equal(keep.sum(axis=1), batch.count):
        return batch
    # the four float fields compacted as one (4, n, k) stack (numba ``_compact_kernel``;
    # measured alone on 2000 poses of the stack room's built map, 896 rows with echoes
    # dropped: numpy's argsort and take_along_axis 2.7-2.9 ms, this pass 0.5-0.6 ms)
    f = np.stack([batch.range_m, batch.cos_doppler, batch.amplitude,
                  batch.arrival_bearing_rad])
    count, f, order, walls, points = _k.compact_rows(keep, f, batch.order, batch.walls,
                                                     batch.points_m, parallel)
    return dataclasses.replace(
        batch, count=count, range_m=f[0], cos_doppler=f[1], amplitude=f[2],
        order=order, walls=walls, points_m=points, arrival_bearing_rad=f[3])


def explanation(tables: SensorTables, measurement: Measurement, poses: FloatArray
                ) -> Explanation:
    """Echo log-likelihood and explained / heard shares of each pose (n, 3).

    Raises
    ------
    ValueError
        The measurement was not prepared for the echo model.
    """
    if measurement.peaks is None:
        raise ValueError("measurement was not prepared for model 'echo' (no peaks)")
    peaks = measurement.peaks._replace(sig_c=cos_sigma(tables, measurement))
    if tables.walls.n == 0:
        n = poses.shape[0]
        count = np.zeros(n, dtype=np.int64)
        empty = np.zeros((n, 0))
        out = _k.score_echo(count, empty, empty, empty, peaks, _terms(tables))
    else:
        parallel = poses.shape[0] >= SERIAL_BELOW
        b, sigma = predicted_echoes(tables, measurement.speed_m_s, poses, parallel)
        level = b.amplitude * end_weights(tables.walls, tables.soft_ends[1], b.walls, b.points_m,
                                          parallel)
        dz, refl = tables.config.vertical()
        if dz.size:  # floor / ceiling copies: explain peaks, never expected (level 0)
            copies = 1 + dz.size
            b = with_vertical(b, dz, refl)
            level = np.repeat(level, copies, axis=1)
            level[:, np.arange(level.shape[1]) % copies != 0] = 0.0
            sigma = None if sigma is None else np.repeat(sigma, copies, axis=1)
        # a wall end's weight is whether the echo exists; once heard it has its amplitude
        out = _k.score_echo(b.count, b.range_m, b.cos_doppler, level, peaks,
                            _terms(tables), sigma, b.amplitude, parallel)
    return Explanation(log_likelihood=out[:, 0], explained=out[:, 1], heard=out[:, 2],
                       n_peaks=measurement.n_peaks)


def score_echo_poses(tables: SensorTables, measurement: Measurement, poses: FloatArray
                     ) -> FloatArray:
    """The echo model's score in correlation units, ``1 + ll / ECHO_NATS`` (NaN off the
    active area, as the G models)."""
    ex = explanation(tables, measurement, poses)
    rho = 1.0 + ex.log_likelihood / ECHO_NATS
    iy0, iy1, ix0, ix1 = tables.active
    c = (poses[:, :2] - np.asarray(tables.origin_m)) / tables.resolution_m
    ix, iy = np.floor(c[:, 0] + 0.5), np.floor(c[:, 1] + 0.5)
    on = (ix >= ix0) & (ix < ix1) & (iy >= iy0) & (iy < iy1)
    return np.where(on, rho, math.nan)


def echo_proposals(tables: SensorTables, measurement: Measurement, n: int,
                   rng: np.random.Generator, strongest: int = 3,
                   pair_share: float = 0.0) -> FloatArray:
    """``n`` poses that would hear one of the block's strongest peaks as a wall's specular
    echo (data-driven proposals for a global start or a re-localization).

    A peak at range r and Doppler cosine c is, if it is a first-order echo of wall w, heard
    from a point ``r`` off w along its normal, with the wall at ``+-arccos(c)`` from the
    direction of travel. Each proposal picks a peak (the strongest ``strongest``, equally), a
    wall (longer ones more often), a point along it, a side and a mirror sign, and so lands
    on a pose that explains that echo exactly; a range-only block gets a uniform heading.
    Up to ``pair_share`` of the proposals explain *two* peaks at once
    (:func:`pair_proposals`); the rest, and those that find no pair, one. Poses off the free
    space are replaced by uniform draws over it (as are all ``n`` when the block has no peak
    or the map no wall). The proposals are unweighted: the caller scores them with the block.
    """
    n_pair = int(round(pair_share * n)) if n > 0 else 0
    pairs = (pair_proposals(tables, measurement, n_pair, rng, strongest + 1) if n_pair
             else np.zeros((0, 3)))
    if pairs.shape[0]:
        single = _single_proposals(tables, measurement, n - pairs.shape[0], rng, strongest)
        return np.vstack([pairs, single])
    return _single_proposals(tables, measurement, n, rng, strongest)


def _wall_frames(tables: SensorTables) -> tuple[FloatArray, FloatArray, FloatArray,
                                                FloatArray, FloatArray]:
    """Start and end points, length, unit direction and unit normal (left of the direction)
    of each map wall of non-zero length: (k, 2), (k, 2), (k,), (k, 2), (k, 2)."""
    seg = tables.walls.segments_m
    a, b = seg[:, 0], seg[:, 1]
    length = np.hypot(*(b - a).T)
    ok = length > 1e-6
    a, b, length = a[ok], b[ok], length[ok]
    u = (b - a) / length[:, None]
    return a, b, length, u, np.column_stack([-u[:, 1], u[:, 0]])


def pair_proposals(tables: SensorTables, measurement: Measurement, n: int,
                   rng: np.random.Generator, strongest: int = 4,
                   margin_m: float = 0.5, draws: int = 8) -> FloatArray:
    """Up to ``n`` poses (k, 3), k <= n, that hear two of the block's strongest peaks as the
    specular echoes of two walls.

    Each draw picks two peaks (ranges r1, r2), two walls at least 15 deg apart (longer ones
    more often) and a side of each: the robot is where the two walls' lines offset by r1 and
    r2 cross, and both specular points must lie on their walls (within ``margin_m`` of the
    ends, which are uncertain on a built map). Its heading puts the first wall at
    ``+-arccos(c1)`` from the direction of travel, the sign chosen so that the second wall's
    Doppler cosine comes nearest ``c2``; a range-only block gets a uniform heading.
    ``draws`` times ``n`` draws are made (most pairs fail a check: walls parallel or not
    both in reach) and the first ``n`` that pass are returned. A single
    peak fixes the robot only to a line along a wall, so the single-peak proposals land near
    a pose that explains a whole block mostly by chance (measured on the T-hall kidnap: one
    proposal in 288 within 1 cm of the truth); two peaks fix the point. Draws that fail a
    check, or fall off the free space, are dropped.
    """
    peaks = measurement.peaks
    if n <= 0 or peaks is None or peaks.r.shape[0] < 2 or tables.walls.n < 2:
        return np.zeros((0, 3))
    want, n = n, draws * n
    a, _, length, u, normal = _wall_frames(tables)
    if length.size < 2:
        return np.zeros((0, 3))
    k_peaks = min(strongest, peaks.r.shape[0])
    j1 = rng.integers(0, k_peaks, size=n)
    j2 = (j1 + rng.integers(1, k_peaks, size=n)) % k_peaks        # another peak
    p = length / length.sum()
    w1 = rng.choice(length.size, size=n, p=p)
    w2 = rng.choice(length.size, size=n, p=p)
    s1 = rng.choice([-1.0, 1.0], size=n)
    s2 = rng.choice([-1.0, 1.0], size=n)
    n1, n2 = normal[w1], normal[w2]
    det = n1[:, 0] * n2[:, 1] - n1[:, 1] * n2[:, 0]
    good = np.abs(det) > math.sin(math.radians(15.0))
    det = np.where(good, det, 1.0)
    c1 = np.sum(n1 * a[w1], axis=1) + s1 * peaks.r[j1]
    c2 = np.sum(n2 * a[w2], axis=1) + s2 * peaks.r[j2]
    xy = np.column_stack([(c1 * n2[:, 1] - c2 * n1[:, 1]) / det,
                          (n1[:, 0] * c2 - n2[:, 0] * c1) / det])
    for w, s, j, nn in ((w1, s1, j1, n1), (w2, s2, j2, n2)):
        foot = xy - (s * peaks.r[j])[:, None] * nn
        t = np.sum((foot - a[w]) * u[w], axis=1)
        good &= (t >= -margin_m) & (t <= length[w] + margin_m)
    toward1 = np.arctan2(-s1 * n1[:, 1], -s1 * n1[:, 0])           # bearing robot -> wall 1
    toward2 = np.arctan2(-s2 * n2[:, 1], -s2 * n2[:, 0])
    if peaks.use_cos:
        theta = np.arccos(np.clip(peaks.c[j1], -1.0, 1.0))
        travel = np.stack([toward1 - theta, toward1 + theta])      # the two mirror signs
        miss = np.abs(np.cos(toward2[None, :] - travel) - peaks.c[j2][None, :])
        travel = travel[np.argmin(miss, axis=0), np.arange(n)]
        heading = travel + (np.pi if measurement.speed_m_s < 0 else 0.0)
    else:
        heading = rng.uniform(-np.pi, np.pi, size=n)
    cand = np.column_stack([xy, np.angle(np.exp(1j * heading))])
    good &= np.isfinite(cand).all(axis=1)
    cand = cand[good]
    if cand.shape[0]:
        cand = cand[tables.free_at(cand[:, :2])]
    return cand[:want]


def _single_proposals(tables: SensorTables, measurement: Measurement, n: int,
                      rng: np.random.Generator, strongest: int) -> FloatArray:
    """:func:`echo_proposals`' one-peak proposals (``n`` of them)."""
    out = uniform_free_poses(tables, n, rng)
    peaks = measurement.peaks
    if n == 0 or peaks is None or peaks.r.shape[0] == 0 or tables.walls.n == 0:
        return out
    a, b, length, u, normal = _wall_frames(tables)
    if length.size == 0:
        return out
    j = rng.integers(0, min(strongest, peaks.r.shape[0]), size=n)
    w = rng.choice(length.size, size=n, p=length / length.sum())
    t = rng.random(n)[:, None]
    side = rng.choice([-1.0, 1.0], size=n)[:, None]
    foot = a[w] + t * (b[w] - a[w])
    xy = foot + side * peaks.r[j][:, None] * normal[w]
    toward = np.arctan2(*(-side * normal[w])[:, ::-1].T)       # bearing robot -> wall
    if peaks.use_cos:
        theta = np.arccos(np.clip(peaks.c[j], -1.0, 1.0)) * rng.choice([-1.0, 1.0], size=n)
        travel = toward - theta
        heading = travel + (np.pi if measurement.speed_m_s < 0 else 0.0)
    else:
        heading = rng.uniform(-np.pi, np.pi, size=n)
    cand = np.column_stack([xy, np.angle(np.exp(1j * heading))])
    free = tables.free_at(cand[:, :2])
    out[free] = cand[free]
    return out
