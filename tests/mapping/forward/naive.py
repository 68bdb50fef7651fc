"""Plain numpy twins of the numba kernels of :mod:`mapping.forward` (tests only).

``echoes_numpy`` enumerates every wall sequence with ``itertools.product``, builds the image
by explicit mirror matrices and traces it leg by leg; ``render_numpy`` evaluates the
drift-averaged correlation by numerical integration of the PSF table. Slow and written for
reading; ``test_forward.py`` compares them with the kernels on random scenes.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from numpy.typing import NDArray

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
    max_order: int, max_path: float, power: float,
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
            if length > max_path:
                continue
            keys.append(key)
            found.append(dict(
                path_m=length, cos_doppler=0.5 * (float(u @ (A @ travel)) - float(u @ travel)),
                amplitude=float(np.prod(strength[list(seq)])) / length**power, order=order,
                walls=list(seq), points=np.array(pts),
                bearing=math.atan2(pts[-1][1] - s[1], pts[-1][0] - s[0]),
            ))
    return sorted(found, key=lambda e: float(e["path_m"]))  # type: ignore[arg-type]


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
