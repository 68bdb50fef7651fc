"""Which image paths the image-source engine renders, and with what gain.

:func:`prepare_scene` turns a scene and the engine's limits (order, longest path, energy
threshold) into a :class:`PreparedScene`; :func:`traced_gains` enumerates the candidate
images at robot positions (:mod:`mapping.simulate.images`), traces their validity and gives
each the product of its reflection coefficients where the path exists and counts
(:func:`path_gains`), zero elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mapping.signal import SonarConfig
from mapping.simulate._base import SceneLike
from mapping.simulate.ism._config import IsmConfig, range_limit_m, spreading_power
from mapping.simulate.ism._diffraction import EdgePaths, edge_paths
from mapping.simulate.ism._images import ImageSet, candidate_images
from mapping.simulate.ism._trace import TraceResult, trace_images

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PreparedScene:
    """Scene arrays and the path limits of one run.

    Attributes
    ----------
    segments, reflection : ndarray
        Walls (W, 2, 2) and their reflection coefficients (W,).
    order : int
        Highest reflection order enumerated (``IsmConfig.order`` or ``max_order``).
    max_path_m : float
        Longest path kept (inf with a fixed order).
    amplitude_floor : float
        Smallest amplitude kept (relative to a rigid 1 m path).
    automatic : bool
        The order is automatic (enumeration may stop early at ``max_images``).
    max_images : int
        Cap on candidate images per block.
    edges : EdgePaths or None
        Candidate edge-diffracted paths (None: diffraction off).
    """

    segments: FloatArray
    reflection: FloatArray
    order: int
    max_path_m: float
    amplitude_floor: float
    automatic: bool = False
    max_images: int = 20_000
    edges: EdgePaths | None = None


def prepare_scene(scene: SceneLike, config: SonarConfig, engine: IsmConfig) -> PreparedScene:
    """Scene arrays and the limits that decide which image paths are rendered.

    With the automatic order every path no longer than ``max_path_m`` (default one
    period's round trip, ``c P / fs``) and above the energy threshold is kept, up to
    ``max_order``; with a fixed order every valid path up to that order.
    """
    seg = np.asarray(scene.segments(), dtype=np.float64)
    refl = np.asarray(scene.reflection_coefficients(), dtype=np.float64)
    if seg.ndim != 3 or seg.shape[0] == 0:
        raise ValueError("scene must have at least one wall")
    floor = 10.0 ** (engine.energy_threshold_db / 20.0)
    edges = edge_paths(seg, engine.diffraction_order) if engine.diffraction_order else None
    if engine.order is None:
        limit = range_limit_m(config) if engine.max_path_m is None else engine.max_path_m
        # a rigid path of length L has amplitude L**-p; beyond floor**(-1/p) nothing counts
        limit = min(limit, floor ** (-1.0 / spreading_power(engine.spreading)))
        return PreparedScene(
            seg, refl, engine.max_order, float(limit), floor, True, engine.max_images, edges
        )
    return PreparedScene(
        seg, refl, engine.order, float(np.inf), floor, False, engine.max_images, edges
    )


def stretch_images(prepared: PreparedScene, positions_m: FloatArray) -> ImageSet:
    """Candidate images for robot positions (the validity nodes of one stretch).

    With the automatic order the enumeration stops at the last order completed before
    ``max_images`` candidates (then ``ImageSet.truncated``); a fixed order raises instead.
    """
    return candidate_images(
        prepared.segments,
        positions_m,
        prepared.order,
        prepared.max_path_m,
        max_images=prepared.max_images,
        truncate=prepared.automatic,
    )


def path_gains(
    trace: TraceResult, prepared: PreparedScene, spreading: str
) -> FloatArray:
    """Gain of each image at each trace time: the reflection product where the path exists.

    Zero where the path is invalid, longer than ``max_path_m`` or below the amplitude floor.
    """
    with np.errstate(divide="ignore", invalid="ignore"):  # invalid paths have length 0
        amp = np.abs(trace.reflection) * trace.path_length_m ** (-spreading_power(spreading))
    keep = trace.valid & (trace.path_length_m <= prepared.max_path_m)
    keep &= amp >= prepared.amplitude_floor
    return np.where(keep, trace.reflection, 0.0)


def traced_gains(
    prepared: PreparedScene, positions_m: FloatArray, spreading: str
) -> tuple[ImageSet, TraceResult, FloatArray]:
    """Candidate images, their validity trace and gains (see :func:`path_gains`) at the
    robot positions ``positions_m`` (n, 2)."""
    images = stretch_images(prepared, positions_m)
    trace = trace_images(images, prepared.segments, prepared.reflection, positions_m)
    return images, trace, path_gains(trace, prepared, spreading)
