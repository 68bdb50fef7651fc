"""Plain numpy twins of the numba kernels of :mod:`mapping.forward` (tests only).

``echoes_numpy`` enumerates every wall sequence with ``itertools.product``, builds the image
by explicit mirror matrices and traces it leg by leg; ``render_numpy`` evaluates the
drift-averaged correlation by numerical integration of the PSF table; ``regularize_corners``
post-processes exact echo lists as the kernel hears right corners (drop each corner's
order-2 paths, add its vertex echo, re-sort). Slow and written for reading;
``test_forward.py`` and ``test_corners.py`` compare them with the kernels on random scenes.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from numpy.typing import NDArray

from mapping.forward import vertex_paths

FloatArray = NDArray[np.float64]


def _mirror(p0: FloatArray, p1: FloatArray) -> tuple[FloatArray, FloatArray]:
    d = p1 - p0
    n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
    return np.eye(2) - 2.0 * np.outer(n, n), 2.0 * float(p0 @ n) * n


def _hit(p: FloatArray, t: FloatArray, a: FloatArray, b: FloatArray) -> tuple[float, float]:
    """Leg parameter s along p -> t and wall parameter u along a -> b of the crossing."""
    r, d = t - p, b - a
    den = r[0] * d[1] - r[1] * d[0]
    if abs(den) <= 1e-15:
        return math.inf, math.inf
    q = a - p
    return (q[0] * d[1] - q[1] * d[0]) / den, (q[0] * r[1] - q[1] * r[0]) / den


def _inside_corner(seg: FloatArray, a: int, b: int, c: FloatArray, prev: FloatArray) -> bool:
    def rays(w: int) -> list[FloatArray]:
        out = []
        for end in seg[w]:
            e = end - c
            if np.linalg.norm(e) > 1e-9 * max(float(np.linalg.norm(seg[w, 1] - seg[w, 0])), 1.0):
                out.append(e)
        return out

    q = prev - c
    for ea in rays(a):
        for eb in rays(b):
            k = ea[0] * eb[1] - ea[1] * eb[0]
            if abs(k) < 1e-12:
                continue
            if (ea[0] * q[1] - ea[1] * q[0]) * k > 0 and (q[0] * eb[1] - q[1] * eb[0]) * k > 0:
                return True
    return False


def _valid(seg: FloatArray, seq: tuple[int, ...], images: list[FloatArray],
           s: FloatArray) -> list[FloatArray] | None:
    k = len(seq)
    pts: list[FloatArray] = [np.zeros(2)] * k
    p = s
    for m in range(k - 1, -1, -1):
        sp, u = _hit(p, images[m + 1], seg[seq[m], 0], seg[seq[m], 1])
        low = 1e-9 if m == k - 1 else -1e-9
        if not (low < sp < 1.0 - 1e-12 and -1e-9 <= u <= 1.0 + 1e-9):
            return None
        p = p + sp * (images[m + 1] - p)
        pts[m] = p
    chain = [s, *pts, s]
    on = [-1, *seq, -1]
    prev_zero = False
    for m in range(k + 1):
        a, b = chain[m], chain[m + 1]
        if np.linalg.norm(b - a) <= 1e-9:
            if m in (0, k) or prev_zero or not _inside_corner(seg, on[m], on[m + 1], a,
                                                               chain[m - 1]):
                return None
            prev_zero = True
            continue
        prev_zero = False
        for w in range(seg.shape[0]):
            if w in (on[m], on[m + 1]):
                continue
            sp, u = _hit(a, b, seg[w, 0], seg[w, 1])
            if 1e-9 < sp < 1.0 - 1e-9 and -1e-9 <= u <= 1.0 + 1e-9:
                return None
    return pts


def echoes_numpy(
    seg: FloatArray, strength: FloatArray, pose: FloatArray, speed: float, c: float,
    max_order: int, max_path: float, power: float, min_amplitude: float = 0.0,
) -> list[dict[str, object]]:
    """Twin of ``_kernels._pose_echoes``: a list of echo dicts sorted by path length."""
    s = np.asarray(pose[:2], dtype=np.float64)
    h = np.array([math.cos(pose[2]), math.sin(pose[2])])
    travel = -h if speed < 0 else h
    vel = speed * h
    maps = [_mirror(seg[w, 0], seg[w, 1]) for w in range(seg.shape[0])]
    found: list[dict[str, object]] = []
    keys: list[FloatArray] = []
    for order in range(1, max_order + 1):
        for seq in itertools.product(range(seg.shape[0]), repeat=order):
            if any(seq[i] == seq[i + 1] for i in range(order - 1)):
                continue
            A, b = np.eye(2), np.zeros(2)
            images = [s]
            for w in seq:
                A, b = maps[w][0] @ A, maps[w][0] @ b + maps[w][1]
                images.append(A @ s + b)
            if any(np.linalg.norm(s - im) > max_path for im in images[1:]):
                continue
            pts = _valid(seg, seq, images, s)
            if pts is None:
                continue
            key = np.concatenate([A.ravel(), b])
            if any(np.all(np.abs(key - k) < 1e-7) for k in keys):
                continue
            d = s - images[-1]
            length0 = np.linalg.norm(d)
            if length0 <= 1e-6:
                continue
            u = d / length0
            a = A @ vel / c
            da, aa = float(d @ a), float(a @ a)
            length = (da + math.sqrt(da * da + (1 - aa) * length0**2)) / (1 - aa)
            amplitude = float(np.prod(strength[list(seq)])) / length**power
            if length > max_path or abs(amplitude) < min_amplitude:
                continue
            keys.append(key)
            found.append(dict(
                path_m=length, cos_doppler=0.5 * (float(u @ (A @ travel)) - float(u @ travel)),
                amplitude=amplitude, order=order,
                walls=list(seq), points=np.array(pts),
                bearing=math.atan2(pts[-1][1] - s[1], pts[-1][0] - s[0]),
            ))
    return sorted(found, key=lambda e: float(e["path_m"]))  # type: ignore[arg-type]


def regularize_corners(fields: dict[str, np.ndarray], segments_m: FloatArray,
                       strength: FloatArray, poses: FloatArray,
                       corners: list[tuple[int, int, FloatArray]], speed_m_s: float,
                       sound_speed_m_s: float, spreading_power: float, max_path_m: float,
                       min_amplitude: float) -> dict[str, np.ndarray]:
    """Twin of the corner part of ``_kernels._pose_echoes``: padded echo arrays
    (``count``, ``path_m`` (round trip), ``cos_doppler``, ``amplitude``, ``order``,
    ``walls`` (n, k, K), ``points`` (n, k, K, 2), ``bearing``) of the exact paths, with
    every order-2 path of each corner's wall pair replaced by its vertex echo.

    The vertex echo: round trip ``L`` retarded as the exact paths are (the sonar's image is
    its point reflection through the vertex, so ``L = |D - v L / c|`` with ``D = 2 (S -
    C)``), amplitude ``s_i s_j / L**p``, Doppler cosine of the direction to the vertex,
    bounce points both at the vertex. Rows stay sorted by path length; padding as before
    (NaN, order 0, walls -1).
    """
    count = fields["count"]
    n, k = fields["path_m"].shape
    kk = fields["walls"].shape[2]
    valid = np.arange(k)[None, :] < count[:, None]
    if kk >= 2 and corners:
        w = fields["walls"]
        for i, j, _ in corners:
            pair = ((fields["order"] == 2)
                    & (((w[:, :, 0] == i) & (w[:, :, 1] == j))
                       | ((w[:, :, 0] == j) & (w[:, :, 1] == i))))
            valid &= ~pair
    m = len(corners)
    if m == 0 or kk < 2:
        return _compact(fields, valid)
    p = np.asarray(poses, dtype=np.float64)
    dist, heard = vertex_paths(segments_m, p, corners)
    heading = p[:, 2]
    sign = -1.0 if speed_m_s < 0 else 1.0
    t = sign * np.stack([np.cos(heading), np.sin(heading)], axis=1)       # travel
    vel = speed_m_s * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    c = sound_speed_m_s
    names = ("path_m", "cos_doppler", "amplitude", "order", "walls", "points", "bearing")
    new: dict[str, list[np.ndarray]] = {key: [] for key in names}
    ok = heard.copy()
    for col, (i, j, vertex) in enumerate(corners):
        q = vertex[None, :] - p[:, :2]                         # sonar -> vertex
        d = np.maximum(dist[:, col], 1e-12)
        u_to = q / d[:, None]
        big_d = -2.0 * q                                        # D = S - I = 2 (S - C)
        a = -vel / c                                            # A v / c with A = -I
        da = np.sum(big_d * a, axis=1)
        aa = np.sum(a * a, axis=1)
        length0 = 2.0 * d
        length = (da + np.sqrt(da * da + (1.0 - aa) * length0 ** 2)) / (1.0 - aa)
        amp = strength[i] * strength[j] / length ** spreading_power
        ok[:, col] &= (length <= max_path_m) & (np.abs(amp) >= min_amplitude) & (d > 1e-6)
        new["path_m"].append(length)
        new["cos_doppler"].append(np.sum(u_to * t, axis=1))
        new["amplitude"].append(amp)
        new["order"].append(np.full(n, 2, dtype=np.int64))
        wl = np.full((n, kk), -1, dtype=np.int64)
        wl[:, 0], wl[:, 1] = i, j
        new["walls"].append(wl)
        pts = np.full((n, kk, 2), np.nan)
        pts[:, :2] = vertex
        new["points"].append(pts)
        new["bearing"].append(np.arctan2(q[:, 1], q[:, 0]))
    merged = {key: np.concatenate([fields[key], np.stack(new[key], axis=1)], axis=1)
              for key in new}
    return _compact(merged, np.concatenate([valid, ok], axis=1))


def _compact(fields: dict[str, np.ndarray], valid: NDArray[np.bool_]) -> dict[str, np.ndarray]:
    """Keep the valid entries of each row, sorted by path length, padded as the kernel pads."""
    key = np.where(valid, fields["path_m"], np.inf)
    order = np.argsort(key, axis=1, kind="stable")
    count = valid.sum(axis=1).astype(np.int64)
    kmax = int(count.max()) if count.size else 0
    order = order[:, :kmax]
    keep = np.arange(kmax)[None, :] < count[:, None]
    out: dict[str, np.ndarray] = {"count": count}
    pads = {"path_m": np.nan, "cos_doppler": np.nan, "amplitude": np.nan, "order": 0,
            "walls": -1, "points": np.nan, "bearing": np.nan}
    for name, pad in pads.items():
        arr = fields[name]
        idx = order.reshape(order.shape + (1,) * (arr.ndim - 2))
        taken = np.take_along_axis(arr, idx, axis=1)
        mask = keep.reshape(keep.shape + (1,) * (arr.ndim - 2))
        out[name] = np.where(mask, taken, pad).astype(arr.dtype)
    return out


def padded(found: list[dict[str, object]], max_order: int) -> dict[str, np.ndarray]:
    """One pose's echo dicts (:func:`echoes_numpy`) as the padded arrays of one row."""
    k = len(found)
    out: dict[str, np.ndarray] = {
        "count": np.array([k], dtype=np.int64), "path_m": np.full((1, k), np.nan),
        "cos_doppler": np.full((1, k), np.nan), "amplitude": np.full((1, k), np.nan),
        "order": np.zeros((1, k), dtype=np.int64),
        "walls": np.full((1, k, max_order), -1, dtype=np.int64),
        "points": np.full((1, k, max_order, 2), np.nan), "bearing": np.full((1, k), np.nan)}
    for col, e in enumerate(found):
        for name in ("path_m", "cos_doppler", "amplitude", "order", "bearing"):
            out[name][0, col] = e[name]
        walls = list(e["walls"])  # type: ignore[call-overload]
        out["walls"][0, col, :len(walls)] = walls
        out["points"][0, col, :len(walls)] = e["points"]
    return out


def render_numpy(
    corr: NDArray[np.complex128], up: int, drift: FloatArray, lag: FloatArray, amp: FloatArray,
    half_width: float, coherent: bool, period: int,
) -> FloatArray:
    """Twin of ``_kernels._render_rows`` from the fine correlation table ``corr`` alone: the
    box average ``(1/D) int C(x + d) dd`` by the trapezoid rule on the fine grid."""
    n_rows = drift.shape[0]
    fine = np.arange(corr.size) / up

    def c_at(x: FloatArray) -> NDArray[np.complex128]:
        xm = np.mod(x, period)
        return np.interp(xm, fine, corr.real, period=period) + 1j * np.interp(
            xm, fine, corr.imag, period=period)

    out = np.zeros((n_rows, period))
    for n in range(n_rows):
        acc = np.zeros(period, dtype=np.complex128 if coherent else np.float64)
        for k in range(lag.size):
            d = drift[n, k]
            reach = 0.5 * abs(d) + half_width
            j = np.arange(math.ceil(lag[k] - reach), math.floor(lag[k] + reach) + 1)
            x = j - lag[k]
            if abs(d) < 1e-3:
                v = c_at(x)
            else:
                grid = np.linspace(-0.5, 0.5, max(int(abs(d) * up * 2), 64) + 1) * d
                v = np.trapezoid(c_at(x[:, None] + grid[None, :]), grid, axis=1) / d
            v = amp[k] * v
            if coherent:
                np.add.at(acc, j % period, v)
            else:
                np.add.at(acc, j % period, np.abs(v) ** 2)
        out[n] = np.abs(acc) if coherent else np.sqrt(acc)
    return out
