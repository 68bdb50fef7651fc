"""Floor and ceiling: the vertical images of a sonar between two horizontal planes (issue 16).

The walls are vertical and infinitely tall, so a 3-D room is the 2-D plan times a 1-D cavity
between the floor (z = 0) and the ceiling (z = H), the sonar at height h. Every 2-D echo
path (round trip L2) has copies through the sonar's vertical images: one more vertical
offset ``dz`` (2h off the floor, 2(H - h) off the ceiling, 2H off both, ...), heard at the
round trip ``L3 = sqrt(L2^2 + dz^2)`` with the reflection product of the planes it met and the
3-D spreading ``1 / L3``. The copy keeps the wall path's horizontal geometry, so its Doppler
cosine is the wall path's times ``L2 / L3`` (the motion is horizontal): heard at a larger
range and an angle nearer 90 deg. A ceiling 2.3 m above a sonar puts a copy of a wall 1 m
away 1.5 m behind it - a ghost wall a 2-D model cannot explain. Checked against the raw
simulator (``mapping.simulate.raw``, ``vertical_order=2``): the heat-map peaks of the copies
are where these formulas put them.

:func:`vertical_images` lists the images (the raw simulator renders the same ones);
:func:`with_vertical` adds the copies to an :class:`~mapping.forward.EchoBatch`.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from mapping.forward._echoes import SPREADING_POWER, EchoBatch

FloatArray = NDArray[np.float64]


def vertical_images(sonar_height_m: float | None, ceiling_height_m: float | None,
                    floor_reflection: float, ceiling_reflection: float,
                    bounces: int) -> tuple[FloatArray, FloatArray]:
    """Vertical path lengths ``dz`` (m, increasing) and reflection products of the sonar's
    images in the floor and ceiling with at most ``bounces`` bounces.

    No floor (``sonar_height_m`` None): none. A floor without a ceiling: one image at 2h.
    Images of the same ``dz`` (floor-then-ceiling and ceiling-then-floor, both 2H) are summed.

    Raises
    ------
    ValueError
        A height not positive, the sonar not below the ceiling, a reflection outside [0, 1]
        or ``bounces`` outside 1..6 (naming the parameter).
    """
    _check_vertical(sonar_height_m, ceiling_height_m, floor_reflection, ceiling_reflection,
                    bounces)
    h, top = sonar_height_m, ceiling_height_m
    if h is None:
        return np.zeros(0), np.zeros(0)
    rf, rc = floor_reflection, ceiling_reflection
    found: dict[float, float] = {}
    if top is None:
        found[2.0 * h] = rf
    else:
        for m in range(-bounces, bounces + 1):
            if m != 0 and 2 * abs(m) <= bounces:  # z = 2 m H + h: |m| floor, |m| ceiling
                dz = 2.0 * abs(m) * top
                found[dz] = found.get(dz, 0.0) + rf ** abs(m) * rc ** abs(m)
            n_floor, n_ceiling = (m - 1, m) if m >= 1 else (1 - m, -m)  # z = 2 m H - h
            if n_floor + n_ceiling <= bounces:
                dz = abs(2.0 * m * top - 2.0 * h)
                found[dz] = found.get(dz, 0.0) + rf**n_floor * rc**n_ceiling
    dz_m = np.array(sorted(k for k, v in found.items() if v != 0.0))
    return dz_m, np.array([found[k] for k in dz_m])


def _check_vertical(h: float | None, top: float | None, rf: float, rc: float,
                    bounces: int) -> None:
    if h is not None and not (math.isfinite(h) and h > 0):
        raise ValueError(f"sonar_height_m must be None or > 0 m, got {h!r}")
    if top is not None:
        if h is None:
            raise ValueError("ceiling_height_m needs sonar_height_m")
        if not (math.isfinite(top) and top > h):
            raise ValueError(f"ceiling_height_m must be above the sonar ({h} m), got {top!r}")
    for name, r in (("floor_reflection", rf), ("ceiling_reflection", rc)):
        if not (math.isfinite(r) and 0.0 <= r <= 1.0):
            raise ValueError(f"{name} must be in [0, 1], got {r!r}")
    if not (isinstance(bounces, int | np.integer) and 1 <= bounces <= 6):
        raise ValueError(f"bounces must be an integer in 1..6, got {bounces!r}")


def with_vertical(batch: EchoBatch, dz_m: FloatArray, reflection: FloatArray) -> EchoBatch:
    """``batch`` with every echo followed by its copies through the vertical images.

    Copy v of an echo of one-way range r, Doppler cosine c and amplitude a is at range
    ``r3 = sqrt(r^2 + (dz_v / 2)^2)``, cosine ``c r / r3`` and amplitude
    ``a reflection_v (r / r3)^p`` (p the batch's spreading power); walls, specular points,
    order and bearing are the echo's. Row i then holds ``count[i] * (1 + V)`` echoes, each
    echo's copies right after it (rows are no longer sorted by range).
    """
    dz = np.asarray(dz_m, dtype=np.float64).ravel()
    refl = np.asarray(reflection, dtype=np.float64).ravel()
    if dz.shape != refl.shape:
        raise ValueError(f"dz_m and reflection must have one shape, got {dz.shape}, {refl.shape}")
    if dz.size == 0:
        return batch
    p = SPREADING_POWER[batch.spreading]
    r = batch.range_m[:, :, None]
    r3 = np.sqrt(r**2 + (0.5 * dz[None, None]) ** 2)
    ratio = r / r3
    copies = 1 + dz.size

    def stack(orig: FloatArray, extra: FloatArray) -> FloatArray:
        return np.concatenate([orig[:, :, None], extra], axis=2).reshape(orig.shape[0], -1)

    cos = stack(batch.cos_doppler, batch.cos_doppler[:, :, None] * ratio)
    return replace(
        batch,
        count=batch.count * copies,
        range_m=stack(batch.range_m, r3),
        cos_doppler=cos,
        amplitude=stack(batch.amplitude,
                        batch.amplitude[:, :, None] * refl[None, None] * ratio**p),
        order=np.repeat(batch.order, copies, axis=1),
        walls=np.repeat(batch.walls, copies, axis=1),
        points_m=np.repeat(batch.points_m, copies, axis=1),
        arrival_bearing_rad=np.repeat(batch.arrival_bearing_rad, copies, axis=1),
    )
