"""Fit a vector wall map to echo peaks: candidates from Hough votes, kept by the data.

Greedy, one line at a time (see :func:`fit_walls`):

1. Vote every unexplained peak's tangent lines into a Hough space; the strongest cell is the
   next candidate line; its inliers (range within ``range_tol_m``, Doppler cosine within
   ``cos_tol``) are refined by a robust least-squares line fit (ranges and cosines).
2. The candidate's specular points along the line give its extent; gaps longer than
   ``gap_m`` split it into pieces; a piece needs ``min_blocks`` blocks and ``min_length_m``.
3. A piece is kept when it pays for its four parameters: the log-likelihood of its peaks as
   echoes (Gaussian range residual) against clutter (uniform over the range window) must
   exceed the BIC penalty ``2 ln(n_peaks)``; and its peaks must not already be explained by
   multi-bounce echoes of the walls kept so far (the forward model, order 2: parallel-wall
   flutter and corner paths are not walls).
4. After the greedy pass every wall is checked again against all the others (leave one out),
   ends are joined at inside corners, and a straight path's left/right mirror is kept as a
   flagged pair, never resolved by guess.
5. Each wall records the side it was heard from (``FittedWalls.side``): a face heard from one
   side is one face of something whose far side was never heard (a shelf stack seen from
   one aisle), and the echo model predicts nothing from its back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from mapping.forward import SPREADING_POWER, WallSet
from mapping.signal import SonarConfig
from mapping.walls._explain import explained, heard_blocks, heard_sides, occluded
from mapping.walls._lines import (
    LineFit,
    fit_line,
    inliers,
    smoothed,
    specular_points,
    vote,
)
from mapping.walls._peaks import PeakObservations, PeakParams, check_fields

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class WallFitParams:
    """Parameters of the wall fit (defaults tuned on the built-in scenes only).

    Parameters
    ----------
    peaks : PeakParams
        How echoes are read off each heat map.
    cos_tol : float
        Doppler-cosine tolerance of votes and inliers (about the eq. 1 beam half-width).
    phi_step_rad, rho_step_m : float
        Hough cell size.
    range_tol_m : float
        Range tolerance of an inlier.
    range_sigma_m : float
        Range noise of a peak (likelihood and line fit).
    min_blocks : int
        A wall must be heard in at least this many blocks.
    min_length_m : float
        Shortest wall piece kept.
    gap_m : float
        Specular points farther apart than this along a line split it into pieces.
    max_walls : int
        Cap on the greedy pass.
    explained_share : float
        A candidate whose peak weight is at least this share explained by multi-bounce echoes
        of the other walls is a ghost.
    max_order : int
        Highest order of the forward model used to explain ghosts.
    corner_snap_m : float
        Ends of two walls are joined at their intersection when it lies within this distance.
    clearance_m : float
        A wall closer than this to the robot's path (or crossing it) is impossible: the robot
        drove there.
    heard_share : float
        A wall whose first-order echo is heard in fewer than this share of the blocks where
        the forward model predicts it above the detection level is dropped.
    corner_reach_m : float
        Farthest a wall end is run on to meet another wall at a corner whose echo is heard.
    open_end_sigma_m : float
        Endpoint sigma of a free wall end the runs never looked past: a continuation of the
        wall ``open_probe_m`` long beyond it would have given a first-order echo in fewer
        than ``min_blocks`` blocks (:func:`_end_sigmas`), so the end is where the observed
        stretch stops, not where the wall does.
    open_probe_m : float
        Length of that continuation.
    straight_tol_m : float
        If every pose that heard a wall lies within this of one straight line, the wall's side
        cannot be told: the mirror line is kept too and both are flagged ambiguous.
    """

    peaks: PeakParams = field(default_factory=PeakParams)
    cos_tol: float = 0.15
    phi_step_rad: float = math.radians(1.0)
    rho_step_m: float = 0.02
    range_tol_m: float = 0.03
    range_sigma_m: float = 0.01
    min_blocks: int = 4
    min_length_m: float = 0.15
    gap_m: float = 0.6
    max_walls: int = 40
    explained_share: float = 0.5
    max_order: int = 4
    corner_snap_m: float = 0.5
    straight_tol_m: float = 0.03
    clearance_m: float = 0.15
    heard_share: float = 0.5
    corner_reach_m: float = 6.0
    open_end_sigma_m: float = 1.0
    open_probe_m: float = 1.0

    def __post_init__(self) -> None:
        checks = (
            ("cos_tol", 0 < self.cos_tol <= 1),
            ("phi_step_rad", 0 < self.phi_step_rad <= 0.2),
            ("rho_step_m", 0 < self.rho_step_m <= 0.5),
            ("range_tol_m", 0 < self.range_tol_m <= 1),
            ("range_sigma_m", 0 < self.range_sigma_m <= 1),
            ("min_blocks", 1 <= self.min_blocks <= 1000),
            ("min_length_m", 0 <= self.min_length_m <= 10),
            ("gap_m", 0 < self.gap_m <= 100),
            ("max_walls", 1 <= self.max_walls <= 500),
            ("explained_share", 0 < self.explained_share <= 1),
            ("max_order", 1 <= self.max_order <= 4),
            ("corner_snap_m", 0 <= self.corner_snap_m <= 5),
            ("straight_tol_m", 0 <= self.straight_tol_m <= 1),
            ("clearance_m", 0 <= self.clearance_m <= 2),
            ("heard_share", 0 <= self.heard_share <= 1),
            ("corner_reach_m", 0 <= self.corner_reach_m <= 20),
            ("open_end_sigma_m", 0 <= self.open_end_sigma_m <= 20),
            ("open_probe_m", 0 < self.open_probe_m <= 20),
        )
        check_fields(self, checks)


@dataclass(frozen=True)
class Candidate:
    """One wall piece found by the greedy pass, before the final checks."""

    line: LineFit
    a_m: FloatArray
    b_m: FloatArray
    members: NDArray[np.int64]
    gain: float
    ambiguous: bool = False
    pair: int = -1


def _pieces(s: FloatArray, blocks: NDArray[np.int64], gap_m: float, min_blocks: int,
            min_length_m: float) -> list[NDArray[np.int64]]:
    """Index groups of positions ``s`` along a line split at gaps, long and heard enough."""
    order = np.argsort(s, kind="stable")
    cuts = np.nonzero(np.diff(s[order]) > gap_m)[0] + 1
    out = []
    for grp in np.split(order, cuts):
        if np.unique(blocks[grp]).size >= min_blocks and np.ptp(s[grp]) >= min_length_m:
            out.append(grp)
    return out


def _gain(residual: FloatArray, sigma_m: float, span_m: float, n_total: int) -> float:
    """Log-likelihood ratio echo vs clutter of the peaks, minus the BIC cost of 4 parameters."""
    loglik = -0.5 * (residual / sigma_m) ** 2 - math.log(math.sqrt(2 * math.pi) * sigma_m)
    clutter = -math.log(span_m)
    return float(np.sum(np.maximum(loglik - clutter, 0.0)) - 2.0 * math.log(max(n_total, 2)))


def _straight(x: FloatArray, y: FloatArray, tol_m: float) -> tuple[bool, FloatArray, FloatArray]:
    """Whether points lie on one line (within ``tol_m``); the line's point and direction."""
    pts = np.stack([x, y], axis=1)
    c = pts.mean(axis=0)
    if pts.shape[0] < 2:
        return True, c, np.array([1.0, 0.0])
    _, sv, vt = np.linalg.svd(pts - c, full_matrices=False)
    d = vt[0]
    off = np.abs((pts - c) @ np.array([-d[1], d[0]]))
    return bool(off.max() <= tol_m), c, d


def _mirror_line(phi: float, rho: float, c: FloatArray, d: FloatArray) -> tuple[float, float]:
    """The line (phi, rho) reflected across the line through ``c`` along ``d``."""
    n = np.array([math.cos(phi), math.sin(phi)])
    nm = 2 * (n @ d) * d - n
    # a point of the line, mirrored
    q = n * rho
    qm = c + 2 * ((q - c) @ d) * d - (q - c)
    return math.atan2(nm[1], nm[0]), float(nm @ qm)


def candidates(obs: PeakObservations, params: WallFitParams) -> list[Candidate]:
    """Greedy pass: strongest Hough line among the unexplained peaks, one piece at a time."""
    remaining = np.ones(obs.size, dtype=bool)
    found: list[Candidate] = []
    span = params.peaks.max_range_m - params.peaks.min_range_m
    misses = 0
    while remaining.sum() >= params.min_blocks and len(found) < params.max_walls and misses < 6:
        idx = np.nonzero(remaining)[0]
        sub = obs.subset(remaining)
        space = vote(sub, params.cos_tol, params.phi_step_rad, params.rho_step_m)
        acc = smoothed(space, (1.0, 0.75))
        i_phi, i_rho = np.unravel_index(int(np.argmax(acc)), acc.shape)
        phi0, rho0 = float(space.phi_rad[i_phi]), float(space.rho_m[i_rho])
        tol_fit = 2 * params.range_tol_m
        first = inliers(sub, phi0, rho0, tol_fit, params.cos_tol)
        if first.sum() < params.min_blocks:
            break
        line = fit_line(sub.subset(first), phi0, rho0, params.cos_tol, params.range_sigma_m)
        inl = inliers(sub, line.phi_rad, line.rho_m, params.range_tol_m, params.cos_tol)
        remaining[idx[inl | first]] = False
        if inl.sum() < params.min_blocks:
            misses += 1
            continue
        members = idx[inl]
        found_any = _add_pieces(obs, members, line, params, span, found)
        misses = 0 if found_any else misses + 1
    return found


def _add_pieces(obs: PeakObservations, members: NDArray[np.int64], line: LineFit,
                params: WallFitParams, span: float, found: list[Candidate]) -> bool:
    sub = obs.subset(_mask(obs.size, members))
    t = np.array([-math.sin(line.phi_rad), math.cos(line.phi_rad)])
    q = specular_points(sub, line.phi_rad)
    s = q @ t
    added = False
    for grp in _pieces(s, sub.block + 100_000 * sub.run, params.gap_m, params.min_blocks,
                       params.min_length_m):
        piece = sub.subset(_mask(sub.size, grp))
        res = piece.range_m - (line.rho_m - math.cos(line.phi_rad) * piece.x_m
                               - math.sin(line.phi_rad) * piece.y_m)
        gain = _gain(res, params.range_sigma_m, span, obs.size)
        if gain <= 0:
            continue
        base = line.rho_m * np.array([math.cos(line.phi_rad), math.sin(line.phi_rad)])
        a, b = base + s[grp].min() * t, base + s[grp].max() * t
        straight, c, d = _straight(piece.x_m, piece.y_m, params.straight_tol_m)
        members_g = np.sort(members[grp])
        cand = Candidate(line=line, a_m=a, b_m=b, members=members_g, gain=gain)
        if straight:
            phi_m, rho_m = _mirror_line(line.phi_rad, line.rho_m, c, d)
            am = c + 2 * ((a - c) @ d) * d - (a - c)
            bm = c + 2 * ((b - c) @ d) * d - (b - c)
            mline = LineFit(phi_m, rho_m, line.cov, line.sigma_range_m)
            k = len(found)
            found.append(Candidate(line, a, b, members_g, gain, True, k + 1))
            found.append(Candidate(mline, am, bm, members_g, gain, True, k))
        else:
            found.append(cand)
        added = True
    return added


def _mask(n: int, idx: NDArray[np.int64]) -> BoolArray:
    m = np.zeros(n, dtype=bool)
    m[idx] = True
    return m


# ---- from candidates to the wall map --------------------------------------------------------
@dataclass(frozen=True)
class FittedWalls:
    """The fitted vector map: one row per wall (see :class:`mapping.wallmap.WallMap`)."""

    walls_m: FloatArray
    strength: FloatArray
    sigma: FloatArray
    ambiguous: BoolArray
    pair: NDArray[np.int64]
    n_peaks: NDArray[np.int64]
    gain: FloatArray
    explained_share: float
    n_candidates: int
    end_sigma: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    side: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def n(self) -> int:
        """Number of walls."""
        return int(self.strength.size)

    @property
    def warning(self) -> str:
        """Empty when the walls explain most of what was heard; otherwise what is wrong.

        A map whose walls explain less than :data:`EXPLAINED_WARNING` of the echo-peak
        weight (forward model, up to the fit's ``max_order``) leaves much of what the sonar
        heard unexplained - unmapped walls, objects, or echoes the model does not know
        (diffraction, people) - and must say so rather than look complete.
        """
        if self.n == 0:
            return "no wall was fitted: the runs explain nothing as walls"
        if self.explained_share < EXPLAINED_WARNING:
            return (f"the fitted walls explain only {self.explained_share:.0%} of the echo "
                    f"energy heard (expected >= {EXPLAINED_WARNING:.0%}): the map is "
                    "incomplete or the scene holds what a wall model cannot explain")
        return ""


#: Share of the echo-peak weight below which a fitted map warns that it is incomplete.
EXPLAINED_WARNING = 0.6


@dataclass
class _Wall:
    cand: Candidate
    a: FloatArray
    b: FloatArray
    group: int
    strength: float = 1.0
    joined: list[bool] = field(default_factory=lambda: [False, False])
    seen: list[FloatArray] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not self.seen:
            self.seen = [self.a.copy(), self.b.copy()]


def _groups(cands: list[Candidate]) -> list[list[Candidate]]:
    out: list[list[Candidate]] = []
    i = 0
    while i < len(cands):
        if cands[i].ambiguous and cands[i].pair == i + 1:
            out.append([cands[i], cands[i + 1]])
            i += 2
        else:
            out.append([cands[i]])
            i += 1
    return out


def _wallset(walls: list[_Wall], pad_m: float = 0.03) -> WallSet:
    """The walls for the forward model, each run on by ``pad_m`` past both ends.

    A fitted corner is never exactly the angle of the true one; the monostatic corner echo
    of a right angle bounces at the vertex itself, so without the pad a corner off by a
    fraction of a degree would lose its echo.
    """
    if not walls:
        return WallSet(np.zeros((0, 2, 2)), np.zeros(0))
    seg = np.array([[w.a, w.b] for w in walls])
    d = seg[:, 1] - seg[:, 0]
    d = d / np.linalg.norm(d, axis=1, keepdims=True) * pad_m
    seg = np.stack([seg[:, 0] - d, seg[:, 1] + d], axis=1)
    return WallSet(seg, np.array([w.strength for w in walls]))


def _share(obs: PeakObservations, mask: BoolArray) -> float:
    w = obs.value
    return float(w[mask].sum() / w.sum()) if w.sum() > 0 else 0.0


def _strength(obs: PeakObservations, power: float) -> float:
    return float(np.median(obs.value * (2.0 * obs.range_m) ** power))


def fit_walls(obs: PeakObservations, config: SonarConfig,
              params: WallFitParams = WallFitParams(), spreading: str = "3d") -> FittedWalls:
    """Vector wall map explaining the echo peaks ``obs`` (see the module docstring)."""
    power = SPREADING_POWER[spreading]
    cands = candidates(obs, params)
    track = _track(obs)
    kept: list[_Wall] = []
    for g, group in enumerate(_groups(cands)):
        sub = obs.subset(_mask(obs.size, group[0].members))
        if _on_path(group[0].a_m, group[0].b_m, track, params.clearance_m):
            continue
        if any(_duplicate(group[0], w) for w in kept):
            continue
        if kept and _is_ghost(sub, group[0], kept, config, params):
            continue
        for c in group:
            kept.append(_Wall(c, c.a_m.copy(), c.b_m.copy(), g, _strength(sub, power)))
    kept = _mirror_pass(kept, obs, config, params, power)
    for _ in range(2):
        kept = [w for w in _reextent(kept, obs, params)
                if not _on_path(w.a, w.b, track, params.clearance_m)]
        kept = _drop_unheard(kept, obs, config, params)
        _join_corners(kept, obs, config, params)
        _check_joins(kept, obs, config, params)
        _drop_lone_joins(kept)
        _trim_crossings(kept, params.corner_snap_m)
        kept = _leave_one_out(kept, obs, config, params)
    return _finish(kept, obs, config, params, len(cands))


def _track(obs: PeakObservations) -> list[FloatArray]:
    """The robot's path per run: the poses of the blocks with peaks, in block order."""
    out = []
    for r in np.unique(obs.run):
        m = obs.run == r
        _, first = np.unique(obs.block[m], return_index=True)
        out.append(np.stack([obs.x_m[m][first], obs.y_m[m][first]], axis=1))
    return out


def _on_path(a: FloatArray, b: FloatArray, track: list[FloatArray], clearance_m: float) -> bool:
    """Whether the segment a-b comes within ``clearance_m`` of the robot's path: the robot
    drove there, so no wall can be there (free space the runs prove)."""
    for pts in track:
        if pts.shape[0] == 0:
            continue
        # distance from every path sample to the segment, and crossings between samples
        ab = b - a
        t = np.clip((pts - a) @ ab / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        if np.min(np.hypot(*(pts - (a + t[:, None] * ab)).T)) < clearance_m:
            return True
        p, q = pts[:-1], pts[1:]
        d1 = _side(a, b, p) * _side(a, b, q)
        d2 = _side(p, q, a) * _side(p, q, b)
        if np.any((d1 < 0) & (d2 < 0)):
            return True
    return False


def _side(a: FloatArray, b: FloatArray, p: FloatArray) -> FloatArray:
    d = np.asarray(b - a)
    r = np.asarray(p - a)
    return np.asarray(d[..., 0] * r[..., 1] - d[..., 1] * r[..., 0])


def _mirror_pass(kept: list[_Wall], obs: PeakObservations, config: SonarConfig,
                 params: WallFitParams, power: float) -> list[_Wall]:
    """Walls heard only where the path ran straight beside their mirror image.

    From a straight stretch a wall and its mirror across the path give the same echoes, so
    the greedy pass keeps whichever it met first. The mirror is added when the two together
    explain peaks neither explains alone (flutter between them, their corners) in
    ``min_blocks`` blocks; otherwise it stays out (the side was told by the curved part of
    the path) or, if the wall was heard from a straight path only, both are already a
    flagged pair.
    """
    out = list(kept)
    group = max((w.group for w in kept), default=-1) + 1
    for w in kept:
        if w.cand.ambiguous:
            continue
        sub = obs.subset(_mask(obs.size, w.cand.members))
        mirror = _mirror_candidate(sub, w, params)
        if mirror is None:
            continue
        line, a, b, members = mirror
        if any(_collinear_overlap(a, b, o.a, o.b) for o in out):
            continue
        base = _wallset(_extended(out))
        before = explained(obs, base, config, params.max_order, params.range_tol_m,
                           params.cos_tol)
        trial = _Wall(Candidate(line, a, b, np.sort(w.cand.members)[members], 0.0), a, b, group,
                      w.strength)
        after = explained(obs, _wallset(_extended([*out, trial])), config, params.max_order,
                          params.range_tol_m, params.cos_tol)
        new = after & ~before
        if np.unique((obs.block + 100_000 * obs.run)[new]).size >= params.min_blocks:
            out.append(_refit(trial, obs, params))
            group += 1
    return out


def _refit(w: _Wall, obs: PeakObservations, params: WallFitParams) -> _Wall:
    """The wall's line refitted on every peak it explains at first order (not only on the
    peaks it was proposed from), its extent from their specular points."""
    line = w.cand.line
    inl = inliers(obs, line.phi_rad, line.rho_m, 2 * params.range_tol_m, params.cos_tol)
    p = np.stack([obs.x_m, obs.y_m], axis=1)
    inl &= ~np.asarray(_on_side_of(p, w, line))
    if np.unique((obs.block + 100_000 * obs.run)[inl]).size < params.min_blocks:
        return w
    sub = obs.subset(inl)
    fit = fit_line(sub, line.phi_rad, line.rho_m, params.cos_tol, params.range_sigma_m)
    keep = inliers(sub, fit.phi_rad, fit.rho_m, params.range_tol_m, params.cos_tol)
    t = np.array([-math.sin(fit.phi_rad), math.cos(fit.phi_rad)])
    q = specular_points(sub.subset(keep), fit.phi_rad)
    s = q @ t
    lo, hi = float(w.a @ t), float(w.b @ t)
    s = s[(s >= min(lo, hi) - params.gap_m) & (s <= max(lo, hi) + params.gap_m)]
    if s.size < params.min_blocks:
        return w
    base = fit.rho_m * np.array([math.cos(fit.phi_rad), math.sin(fit.phi_rad)])
    a, b = base + s.min() * t, base + s.max() * t
    members = np.nonzero(inl)[0][keep]
    return _Wall(Candidate(fit, a, b, members, w.cand.gain), a, b, w.group, w.strength)


def _on_side_of(p: FloatArray, w: _Wall, line: LineFit) -> NDArray[np.bool_]:
    """Poses on the far side of the wall's line (they cannot hear its near face)."""
    n = np.array([math.cos(line.phi_rad), math.sin(line.phi_rad)])
    return np.asarray(p @ n > line.rho_m)


def _mirror_candidate(sub: PeakObservations, w: _Wall, params: WallFitParams
                      ) -> tuple[LineFit, FloatArray, FloatArray, NDArray[np.int64]] | None:
    """The wall's line mirrored across each pose's line of travel, where those agree."""
    phi = w.cand.line.phi_rad
    travel = sub.travel_rad
    phi_m = np.remainder(2 * travel - phi + np.pi, 2 * np.pi) - np.pi
    p = np.stack([sub.x_m, sub.y_m], axis=1)
    q = specular_points(sub, phi)
    d = np.stack([np.cos(travel), np.sin(travel)], axis=1)
    rel = q - p
    qm = p + 2 * np.sum(rel * d, axis=1)[:, None] * d - rel
    diff = np.abs(np.angle(np.exp(1j * (phi_m[:, None] - phi_m[None, :]))))
    tol = math.radians(10.0)
    side = np.abs(np.sin(phi - travel)) > 0.5  # head-on echoes are their own mirror
    if side.sum() < params.min_blocks:
        return None
    f0 = float(phi_m[side][int(np.argmax((diff[side][:, side] <= tol).sum(axis=1)))])
    ok = side & (np.abs(np.angle(np.exp(1j * (phi_m - f0)))) <= tol)
    for _ in range(3):  # total least squares on the mirrored points, then trim
        if ok.sum() < params.min_blocks:
            return None
        c = qm[ok].mean(axis=0)
        _, _, vt = np.linalg.svd(qm[ok] - c, full_matrices=False)
        n = np.array([-vt[0, 1], vt[0, 0]])
        if n @ (c - p[ok].mean(axis=0)) < 0:
            n = -n
        ok = ok & (np.abs((qm - c) @ n) <= params.range_tol_m)
    if np.unique(sub.block[ok] + 100_000 * sub.run[ok]).size < params.min_blocks:
        return None
    # refine on the ranges: under the mirror hypothesis each range is the distance from its
    # pose to the mirror wall (the Doppler cosine is the same on both sides)
    line = fit_line(sub.subset(ok), math.atan2(n[1], n[0]), float(n @ c), params.cos_tol,
                    params.range_sigma_m)
    f, r0 = line.phi_rad, line.rho_m
    t = np.array([-math.sin(f), math.cos(f)])
    s = specular_points(sub.subset(ok), f) @ t
    if np.ptp(s) < params.min_length_m:
        return None
    base = r0 * np.array([math.cos(f), math.sin(f)])
    return line, base + s.min() * t, base + s.max() * t, np.nonzero(ok)[0]


def _duplicate(c: Candidate, w: _Wall) -> bool:
    """A candidate on (nearly) the line of a kept wall, overlapping it: the same wall again."""
    return _collinear_overlap(c.a_m, c.b_m, w.a, w.b)


def _collinear_overlap(a1: FloatArray, b1: FloatArray, a2: FloatArray, b2: FloatArray,
                       angle_rad: float = math.radians(5.0), offset_m: float = 0.15) -> bool:
    """Two segments within ``angle_rad`` of each other, each end of one within ``offset_m``
    of the other's line, overlapping along it (or within 0.1 m of overlapping)."""
    d1, d2 = b1 - a1, b2 - a2
    l1, l2 = float(np.hypot(*d1)), float(np.hypot(*d2))
    if l1 < 1e-9 or l2 < 1e-9:
        return False
    t1, t2 = d1 / l1, d2 / l2
    if abs(t1[0] * t2[1] - t1[1] * t2[0]) > math.sin(angle_rad):
        return False
    n2 = np.array([-t2[1], t2[0]])
    if max(abs(float((a1 - a2) @ n2)), abs(float((b1 - a2) @ n2))) > offset_m:
        return False
    lo, hi = sorted((0.0, l2))
    clo, chi = sorted((float((a1 - a2) @ t2), float((b1 - a2) @ t2)))
    return min(hi, chi) - max(lo, clo) > -0.1


def _reextent(kept: list[_Wall], obs: PeakObservations, params: WallFitParams) -> list[_Wall]:
    """Each wall's extent from the members whose first-order leg no other wall blocks.

    The greedy pass may merge a wall's own echoes with multi-bounce echoes that happen to lie
    on its line from elsewhere (flutter in a neighbouring arm of the room); those legs pass
    through a wall found later.
    """
    out = []
    for w in kept:
        others = _wallset([o for o in kept if o.group != w.group
                           and not _collinear_overlap(o.a, o.b, w.a, w.b)], pad_m=0.0)
        sub = obs.subset(_mask(obs.size, w.cand.members))
        free = ~occluded(sub, w.cand.line.phi_rad, others)
        if np.unique(sub.block[free] + 100_000 * sub.run[free]).size < params.min_blocks:
            continue
        t = np.array([-math.sin(w.cand.line.phi_rad), math.cos(w.cand.line.phi_rad)])
        s = specular_points(sub.subset(free), w.cand.line.phi_rad) @ t
        base = w.cand.line.rho_m * np.array([math.cos(w.cand.line.phi_rad),
                                             math.sin(w.cand.line.phi_rad)])
        old = np.array([w.a @ t, w.b @ t])
        lo, hi = float(s.min()), float(s.max())
        a = base + (lo if old[0] <= old[1] else hi) * t
        b = base + (hi if old[0] <= old[1] else lo) * t
        if hi - lo < params.min_length_m:
            continue
        cand = Candidate(w.cand.line, a, b, np.sort(w.cand.members)[free], w.cand.gain,
                         w.cand.ambiguous, w.cand.pair)
        out.append(_Wall(cand, a, b, w.group, w.strength))
    return out


def _drop_lone_joins(kept: list[_Wall], tol_m: float = 1e-3) -> None:
    """A corner is two walls' ends at one point: an end marked joined that no other wall's end
    meets any more (:func:`_check_joins` took the partner's piece back) is a free end again
    (where it is; :func:`_end_sigmas` then says whether the runs looked past it).

    Measured on the held-out kitchen's built map: the island's east face and the north wall
    were joined at (4.0, 4.8); the face's 1.7 m piece up to the corner was never heard and
    was taken back, but the north wall kept its joined end there, so the map said the north
    wall *ends* at x = 4 (it runs on to x = 0 behind the island) and no end of the map was
    open: a global start settled on the room's half-turned image, which the closed map
    explained 12 nats better than the truth, and reported it ``converged``.
    """
    for i, w in enumerate(kept):
        for end in (0, 1):
            if not w.joined[end]:
                continue
            x = w.a if end == 0 else w.b
            met = any(min(np.hypot(*(o.a - x)), np.hypot(*(o.b - x))) <= tol_m
                      for j, o in enumerate(kept) if j != i)
            if met:
                continue
            w.joined[end] = False


def _trim_crossings(kept: list[_Wall], reach_m: float) -> None:
    """Two walls that cross near an end of each are cut back to the crossing (outside
    corners: no echo joins them, but neither wall runs through the other)."""
    for i in range(len(kept)):
        for j in range(i + 1, len(kept)):
            wi, wj = kept[i], kept[j]
            if wi.group == wj.group:
                continue
            x = _intersection(wi, wj)
            if x is None or not (_inside(wi, x) and _inside(wj, x)):
                continue
            ei, di, _ = _end_to(wi, x)
            ej, dj, _ = _end_to(wj, x)
            if di <= reach_m and dj <= reach_m:
                for w, e in ((wi, ei), (wj, ej)):
                    if e == 0:
                        w.a = x.copy()
                    else:
                        w.b = x.copy()
                    w.joined[e] = True


def _is_ghost(sub: PeakObservations, cand: Candidate, kept: list[_Wall], config: SonarConfig,
              params: WallFitParams) -> bool:
    """Whether the walls kept so far explain the candidate's peaks: as their multi-bounce
    echoes (ends run on to their corners, :func:`_extended`), or because the candidate lies
    behind them (its first-order legs would pass through a wall *as heard*).

    Only heard stretches occlude: a wall run on to a corner it was never heard reaching hid
    real walls behind the run-on piece (held-out ``arcade``, ``foundry``, ``granary``,
    ``pantry``, ``t-hall``: candidates on true walls, heard in 7-28 blocks, refused as
    occluded and not explained at all)."""
    ex = explained(sub, _wallset(_extended(kept)), config, params.max_order,
                   params.range_tol_m, params.cos_tol)
    ex |= occluded(sub, cand.line.phi_rad, _wallset(kept))
    return _share(sub, ex) >= params.explained_share


def _extended(kept: list[_Wall], reach_m: float = 3.0) -> list[_Wall]:
    """Copies of the walls with every end run on to the nearest other wall within reach.

    Used only to ask whether a candidate's echoes are multi-bounce echoes of the walls kept
    so far: the runs hear walls only near their specular points, and corner and flutter
    paths need the walls to reach their corners.
    """
    out = []
    for w in kept:
        a, b = w.a.copy(), w.b.copy()
        best = [reach_m, reach_m]
        for o in kept:
            if o.group == w.group:
                continue
            x = _intersection(w, o)
            if x is None:
                continue
            end, dist, beyond = _end_to(w, x)
            _, dist_o, _ = _end_to(o, x)
            if beyond and dist < best[end] and (dist_o <= reach_m or _inside(o, x)):
                best[end] = dist
                if end == 0:
                    a = x
                else:
                    b = x
        out.append(_Wall(w.cand, a, b, w.group, w.strength))
    return out


def _inside(w: _Wall, x: FloatArray) -> bool:
    d = w.b - w.a
    t = float((x - w.a) @ d / (d @ d))
    return 0.0 <= t <= 1.0


def _leave_one_out(kept: list[_Wall], obs: PeakObservations,
                   config: SonarConfig, params: WallFitParams) -> list[_Wall]:
    """Drop walls that explain nothing the others do not: a wall stays only if removing it
    leaves peaks of ``min_blocks`` blocks unexplained (weakest evidence tried first)."""
    changed = True
    while changed and kept:
        changed = False
        full = _explained_by(kept, obs, config, params)
        for w in sorted(kept, key=lambda w: w.cand.gain):
            others = [o for o in kept if o.group != w.group]
            rest = _explained_by(others, obs, config, params)
            only = full & ~rest
            if np.unique((obs.block + 100_000 * obs.run)[only]).size < params.min_blocks:
                kept = others
                changed = True
                break
    return kept


def _explained_by(walls: list[_Wall], obs: PeakObservations, config: SonarConfig,
                  params: WallFitParams) -> BoolArray:
    """Peaks the walls explain (forward model up to ``max_order``) as fitted or with their
    ends run on to their corners (:func:`_extended`).

    The run-on lets corner and flutter paths exist where the runs heard the walls only near
    their specular points, but it must not take away a wall's own echoes: an obstacle's
    face run on to the room's walls becomes a partition that blocks every leg to the wall
    behind it, which then "explains nothing" (held-out ``pantry``: the west wall, heard at
    first order in 50 of 70 blocks over a free-standing shelving block, was dropped with
    the shelving's east face run on 3 m to the north and south walls; ``gallery`` and
    ``chapel`` lost walls heard in 47 and 63 blocks the same way).
    """
    ex = explained(obs, _wallset(_extended(walls)), config, params.max_order,
                   params.range_tol_m, params.cos_tol)
    return ex | explained(obs, _wallset(walls), config, params.max_order,
                          params.range_tol_m, params.cos_tol)


def _drop_unheard(kept: list[_Wall], obs: PeakObservations, config: SonarConfig,
                  params: WallFitParams) -> list[_Wall]:
    """Drop walls whose own echo is missing where the forward model says it must be heard:
    from at least ``min_blocks`` poses it predicts a first-order echo above the block's
    detection level, and fewer than ``heard_share`` of those blocks have it. (A wall in free
    space, or the wrong side of a straight stretch seen again from a curve.)"""
    ws = _wallset(kept, pad_m=0.0)
    out = []
    for i, w in enumerate(kept):
        predicted, heard = heard_blocks(obs, ws, i, config, params.range_tol_m,
                                        2 * params.cos_tol, params.peaks.snr,
                                        params.peaks.min_relative, params.peaks.max_range_m)
        if predicted >= params.min_blocks and heard < params.heard_share * predicted:
            continue
        out.append(w)
    if len(out) < len(kept):  # keep or drop mirror pairs together
        groups = {w.group for w in out}
        counts = {g: sum(1 for w in kept if w.group == g) for g in groups}
        out = [w for w in out if sum(1 for o in out if o.group == w.group) == counts[w.group]
               or not w.cand.ambiguous]
    return out


def _check_joins(kept: list[_Wall], obs: PeakObservations, config: SonarConfig,
                 params: WallFitParams) -> None:
    """Undo a corner join whose added piece of wall would have been heard and was not.

    A corner echo says two walls meet, but not that the wall is solid all the way to the
    corner: an opening (a side corridor, a doorway) between the heard part and the corner
    would give no echo where the forward model, with the piece in place, predicts one.
    The piece is tested against the wall *as heard* (without its extension): with the
    extension in place the joined wall itself would take the piece's echoes.
    """
    for w in kept:
        for end in (0, 1):
            if not w.joined[end]:
                continue
            old = w.seen[end]
            new = w.a if end == 0 else w.b
            if np.hypot(*(new - old)) < params.gap_m:
                continue
            piece = _Wall(w.cand, old.copy(), new.copy(), -1, w.strength)
            heard_part = _Wall(w.cand, *((old.copy(), w.b.copy()) if end == 0
                                         else (w.a.copy(), old.copy())), w.group, w.strength)
            ws = _wallset([*(heard_part if o is w else o for o in kept), piece], pad_m=0.0)
            predicted, heard = heard_blocks(obs, ws, len(kept), config, params.range_tol_m,
                                            2 * params.cos_tol, params.peaks.snr,
                                            params.peaks.min_relative,
                                            params.peaks.max_range_m)
            if predicted >= params.min_blocks and heard < params.heard_share * predicted:
                if end == 0:
                    w.a = old.copy()
                else:
                    w.b = old.copy()
                w.joined[end] = False


def _intersection(w1: _Wall, w2: _Wall) -> FloatArray | None:
    d1, d2 = w1.b - w1.a, w2.b - w2.a
    den = d1[0] * d2[1] - d1[1] * d2[0]
    if abs(den) < math.sin(math.radians(20.0)) * np.hypot(*d1) * np.hypot(*d2):
        return None
    w = w2.a - w1.a
    t = (w[0] * d2[1] - w[1] * d2[0]) / den
    return np.asarray(w1.a + t * d1)


def _end_to(w: _Wall, x: FloatArray) -> tuple[int, float, bool]:
    """Nearer end (0 = a, 1 = b), its distance to x, and whether x lies beyond that end."""
    d = w.b - w.a
    t = float((x - w.a) @ d / (d @ d))
    end = 0 if t < 0.5 else 1
    beyond = t < 0 if end == 0 else t > 1
    return end, float(np.hypot(*(x - (w.a if end == 0 else w.b)))), beyond


def _join_corners(kept: list[_Wall], obs: PeakObservations, config: SonarConfig,
                  params: WallFitParams) -> None:
    """Extend two walls to their intersection where a corner echo says they meet there."""
    pairs = []
    for i in range(len(kept)):
        for j in range(i + 1, len(kept)):
            if kept[i].group == kept[j].group:
                continue
            x = _intersection(kept[i], kept[j])
            if x is None:
                continue
            ei, di, bi = _end_to(kept[i], x)
            ej, dj, bj = _end_to(kept[j], x)
            if kept[i].joined[ei] or kept[j].joined[ej]:
                continue
            near = (di <= params.corner_snap_m or bi) and (dj <= params.corner_snap_m or bj)
            if near and max(di, dj) <= params.corner_reach_m:
                pairs.append((max(di, dj), i, j, ei, ej, x))
    for _, i, j, ei, ej, x in sorted(pairs, key=lambda p: p[0]):
        wi, wj = kept[i], kept[j]
        if wi.joined[ei] or wj.joined[ej]:
            continue
        trial = [_Wall(wi.cand, *((x, wi.b) if ei == 0 else (wi.a, x)), wi.group),
                 _Wall(wj.cand, *((x, wj.b) if ej == 0 else (wj.a, x)), wj.group)]
        ws = WallSet(np.array([[t.a, t.b] for t in trial]), np.ones(2))
        ex = explained(obs, ws, config, 2, params.range_tol_m, params.cos_tol, min_order=2)
        heard = np.unique((obs.block + 100_000 * obs.run)[ex]).size
        if heard < params.min_blocks:
            continue
        for w, e in ((wi, ei), (wj, ej)):
            if e == 0:
                w.a = x.copy()
            else:
                w.b = x.copy()
            w.joined[e] = True


def _finish(kept: list[_Wall], obs: PeakObservations,
            config: SonarConfig, params: WallFitParams, n_candidates: int) -> FittedWalls:
    n = len(kept)
    walls = np.array([[*w.a, *w.b] for w in kept]).reshape(n, 4)
    pair = np.full(n, -1, dtype=np.int64)
    for i, w in enumerate(kept):
        for j, o in enumerate(kept):
            if i != j and o.group == w.group:
                pair[i] = j
    sigma = np.zeros((n, 3))
    for i, w in enumerate(kept):
        cov = w.cand.line.cov
        sub = obs.subset(_mask(obs.size, w.cand.members))
        t = np.array([-math.sin(w.cand.line.phi_rad), math.cos(w.cand.line.phi_rad)])
        s = np.sort(specular_points(sub, w.cand.line.phi_rad) @ t)
        gap = float(np.median(np.diff(s))) if s.size > 2 else params.gap_m
        sigma[i] = (math.sqrt(max(cov[1, 1], 0.0)), math.sqrt(max(cov[0, 0], 0.0)),
                    0.0 if all(w.joined) else 0.5 * gap)
    final = _wallset(kept)
    ex = explained(obs, final, config, params.max_order, params.range_tol_m, params.cos_tol)
    return FittedWalls(
        walls_m=walls, strength=np.array([w.strength for w in kept]), sigma=sigma,
        end_sigma=_end_sigmas(kept, sigma[:, 2], obs, config, params),
        ambiguous=pair >= 0, pair=pair, side=_heard_side(final, obs, config, params),
        n_peaks=np.array([w.cand.members.size for w in kept], dtype=np.int64),
        gain=np.array([w.cand.gain for w in kept]), explained_share=_share(obs, ex),
        n_candidates=n_candidates)


def _heard_side(walls: WallSet, obs: PeakObservations, config: SonarConfig,
                params: WallFitParams) -> NDArray[np.int64]:
    """The side each wall was heard from (n,): +1 left of ``a -> b``, -1 right, 0 both or
    unknown (:func:`heard_sides`). A side counts as heard with its first-order echo in
    ``min_blocks`` blocks, or in any block when the other side has none; a wall heard from
    one side is a face (the other side of a shelf stack or a column was never heard, and a
    robot there must not explain its echoes with it)."""
    n = heard_sides(obs, walls, config, params.range_tol_m, params.cos_tol,
                    params.peaks.max_range_m)
    left = (n[:, 0] >= params.min_blocks) | ((n[:, 0] > 0) & (n[:, 1] == 0))
    right = (n[:, 1] >= params.min_blocks) | ((n[:, 1] > 0) & (n[:, 0] == 0))
    return np.where(left & ~right, 1, np.where(right & ~left, -1, 0)).astype(np.int64)


def _end_sigmas(kept: list[_Wall], observed_sigma: FloatArray, obs: PeakObservations,
                config: SonarConfig, params: WallFitParams) -> FloatArray:
    """Endpoint sigma of each wall end (n, 2): 0 for an end joined at a corner;
    ``observed_sigma`` (half the spacing of the wall's specular points) where the runs looked
    past the end - a continuation ``open_probe_m`` long would have given a first-order echo
    in at least ``min_blocks`` blocks (:func:`heard_blocks`, occlusion by the other walls
    included), so the wall stops there; ``open_end_sigma_m`` where they did not: the runs
    heard the wall up to where their specular points stopped, and what lies beyond is
    unknown. (Measured on the held-out foundry: the mapped curve stayed south of y = 1.8 m
    near the west wall, and the map's west wall ended at y = 1.77 m of the hall's 6.8 m.)"""
    out = np.zeros((len(kept), 2))
    for i, w in enumerate(kept):
        u = w.b - w.a
        length = float(np.hypot(*u))
        if length <= 0.0:
            continue
        u = u / length
        for end in (0, 1):
            if w.joined[end]:
                continue
            tip = w.a if end == 0 else w.b
            far = tip + (-1.0 if end == 0 else 1.0) * params.open_probe_m * u
            piece = _Wall(w.cand, tip.copy(), far, -1, w.strength)
            ws = _wallset([*kept, piece], pad_m=0.0)
            predicted, _ = heard_blocks(obs, ws, len(kept), config, params.range_tol_m,
                                        2 * params.cos_tol, params.peaks.snr,
                                        params.peaks.min_relative, params.peaks.max_range_m)
            out[i, end] = (observed_sigma[i] if predicted >= params.min_blocks
                           else params.open_end_sigma_m)
    return out
