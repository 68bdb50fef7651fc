"""Parameters of the sensor model (:class:`SensorConfig`); see :mod:`localization.sensor`."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from mapping.forward import vertical_images
from mapping.signal import SonarConfig

FloatArray = NDArray[np.float64]
Model = Literal["correlation", "range", "echo"]

#: Nats of echo log-likelihood per unit of the echo model's score: ``rho = 1 + ll / ECHO_NATS``,
#: so ``beta = ECHO_NATS`` applies the echo likelihood untempered.
ECHO_NATS = 200.0


@dataclass(frozen=True)
class SensorConfig:
    """Parameters of the sensor model.

    Parameters
    ----------
    model : {"correlation", "range", "echo"}
        ``correlation`` and ``range`` compare the heat map with G (the baseline; the paper's
        Fig. 1(b)); "correlation" falls back to "range" for a block without direction
        information (see ``min_speed_m_s``). ``echo`` is the physical model: the echoes the
        map's walls give at each pose (:mod:`mapping.forward`: specular points, inside
        corners, orders up to ``echo_order``) against the peaks of the heat map; it needs a
        map with walls and reads range only while the robot stands still.
    n_angles : int
        Directions of the full-circle polar grid (72 = 5 deg); also the grid filter's
        heading bins.
    range_step_m, min_range_m, max_range_m : float
        Range bins ``min_range_m + k * range_step_m`` below ``max_range_m``.
    n_headings : int
        Heading bins of the direction table (1 deg by default); a multiple of ``n_angles``.
    beta : float
        Sharpness: log-likelihood ``beta * (rho - 1)`` before the floor.
    z_rand : float
        Weight of the uniform floor in (0, 1).
    min_speed_m_s : float
        At ``|speed|`` below this the range-only model is used automatically.
    map_blur_cells : float
        Gaussian blur (standard deviation, cells) applied to G before sampling.
    range_gain_exponent : float
        The measured heat map is multiplied by ``r ** range_gain_exponent`` to undo the
        spreading loss before it is compared with G.
    keep_fraction : float
        Share of the unfolded measurement kept above the noise floor: the
        ``1 - keep_fraction`` quantile is subtracted and negatives set to 0, so the cross
        term of the correlation is a sparse dot product.
    echo_order : int
        Echo model: reflection orders predicted (1..4; 2 = walls and inside corners).
    right_corner_tol_deg : float
        Echo model: walls sharing an end at an angle within this of 90 deg are a right
        corner, heard once at its vertex (a fitted corner is never exactly square, and its
        exact image paths split or vanish: ``ForwardParams.right_corner_tol_deg``); 0 keeps
        the exact image paths.
    range_sigma_m : float
        Echo model: range tolerance of a predicted echo (map error plus peak position).
    cos_sigma_min, cos_sigma_beam : float
        Echo model: Doppler-cosine tolerance ``max(cos_sigma_min, cos_sigma_beam * w)``
        with ``w = c / (2 |v| T f0)`` the width of eq. 1's Doppler beam (one carrier cycle
        of drift over the block).
    clutter : float
        Echo model: likelihood floor of a measured peak no wall explains (people,
        furniture, unmapped walls), relative to a perfectly explained one.
    p_detect : float
        Echo model: probability that a predicted echo at full relative level is heard
        (below 1: occlusion, absorbing surfaces); a missed one costs ``log(1 - p_detect)``.
    detect_lo, detect_hi : float
        Echo model: a predicted echo below ``detect_lo`` of the pose's strongest is not
        expected; the detection probability ramps up to ``p_detect`` at ``detect_hi``.
    amplitude_sigma : float
        Echo model: tolerance (natural log) of a matched peak's level against its predicted
        echo's, after the block's common gain is fitted per pose (0: levels not compared).
        Measured on tracked runs (the simulator at SNR 10 dB, matched isolated echoes):
        scatter 0.18-0.24 on true walls, 0.21-0.43 on built maps; 0.5 leaves room for
        walls whose strength the map got wrong. Not used with ``sonar_height_m`` (a 3-D room:
        floor copies merge with their wall echoes; measured to mislead on raw recordings).
    max_peaks : int
        Echo model: strongest heat-map peaks read per block; twice as many with a floor
        (``sonar_height_m``): the copies double the echoes worth reading (measured on the
        shoebox and pillar runs with wall paths via floor and ceiling: 12 peaks tracked at
        0.7 / 1.4 cm but converged on 34 / 59 % of blocks, 24 at 0.4 / 1.2 cm and 75 / 82 %).
    peak_snr : float
        Echo model: a peak must stand ``peak_snr`` times above the block's median.
    sonar_height_m, ceiling_height_m : float or None
        Echo model: the sonar's height above the floor and the ceiling's (None: a 2-D room).
        Given, every predicted echo gets its copies through the floor and ceiling images
        (:func:`mapping.forward.vertical_images`): a wall echo bounced off the floor arrives
        a few cm later, off the ceiling up to metres later. The copies may explain measured
        peaks (they are not clutter) but are never expected (a missing one costs nothing):
        a block's strongest peaks cannot hold every copy.
    floor_reflection, ceiling_reflection : float
        Echo model: reflection of the floor and the ceiling, in [0, 1].
    vertical_bounces : int
        Echo model: most floor + ceiling bounces of a copy (1..6).
    echo_bank_oversample : int
        Echo model: its heat maps hold this many times the sonar's ``directions`` rows
        (:meth:`heatmap_sonar`). Eq. 1's Doppler beam is about ``4 c / (B v)`` wide in
        cosine, 0.11 at 0.15 m/s, and the paper's 29 directions are 6.2 deg apart, 0.108 in
        cosine near broadside: one row per beam. A parabola through three rows then pulls a
        peak's direction towards the nearest row, by up to 0.026 in cosine (rms 0.011, the
        analytic echo of :mod:`mapping.synthetic`) - a heading bias of 0.4-0.8 deg on
        straight runs a few degrees oblique to their walls. Two rows per beam cut it
        nine-fold (rms 0.0012) for 1.3x the heat map's cost (made outside the filter's
        update). The G models keep the map's own rows (G was built from them); 1 reads
        the map's bank.
    """

    model: Model = "correlation"
    n_angles: int = 72
    range_step_m: float = 0.05
    min_range_m: float = 0.15
    max_range_m: float = 5.0
    n_headings: int = 360
    beta: float = 200.0
    z_rand: float = 0.001
    min_speed_m_s: float = 0.03
    map_blur_cells: float = 1.0
    range_gain_exponent: float = 1.0
    keep_fraction: float = 0.10
    echo_order: int = 2
    right_corner_tol_deg: float = 3.0
    range_sigma_m: float = 0.02
    cos_sigma_min: float = 0.03
    cos_sigma_beam: float = 0.5
    clutter: float = 0.05
    p_detect: float = 0.9
    detect_lo: float = 0.1
    detect_hi: float = 0.4
    amplitude_sigma: float = 0.5
    max_peaks: int = 12
    peak_snr: float = 6.0
    sonar_height_m: float | None = None
    ceiling_height_m: float | None = None
    floor_reflection: float = 0.9
    ceiling_reflection: float = 0.7
    vertical_bounces: int = 2
    echo_bank_oversample: int = 2

    def __post_init__(self) -> None:
        if self.model not in ("correlation", "range", "echo"):
            raise ValueError(
                f"model must be 'correlation', 'range' or 'echo', got {self.model!r}")
        if not 8 <= self.n_angles <= 720 or self.n_angles % 2:
            raise ValueError(f"n_angles must be even in [8, 720], got {self.n_angles}")
        if self.n_headings < self.n_angles or self.n_headings % self.n_angles:
            raise ValueError(
                f"n_headings must be a multiple of n_angles={self.n_angles}, got "
                f"{self.n_headings}"
            )
        if not 0 < self.range_step_m <= 1.0:
            raise ValueError(f"range_step_m must be in (0, 1] m, got {self.range_step_m}")
        if not 0 <= self.min_range_m < self.max_range_m - self.range_step_m:
            raise ValueError(
                "need 0 <= min_range_m < max_range_m - range_step_m, got "
                f"{self.min_range_m}, {self.max_range_m}"
            )
        if not (math.isfinite(self.beta) and self.beta > 0):
            raise ValueError(f"beta must be > 0, got {self.beta}")
        if not 0 < self.z_rand < 1:
            raise ValueError(f"z_rand must be in (0, 1), got {self.z_rand}")
        if not self.min_speed_m_s >= 0:
            raise ValueError(f"min_speed_m_s must be >= 0, got {self.min_speed_m_s}")
        if not 0 < self.keep_fraction <= 1:
            raise ValueError(f"keep_fraction must be in (0, 1], got {self.keep_fraction}")
        if not self.map_blur_cells >= 0:
            raise ValueError(f"map_blur_cells must be >= 0, got {self.map_blur_cells}")
        echo_checks = (
            ("echo_order", "an integer in 1..4",
             isinstance(self.echo_order, int) and self.echo_order in (1, 2, 3, 4)),
            ("right_corner_tol_deg", "in [0, 45] deg", 0 <= self.right_corner_tol_deg <= 45),
            ("range_sigma_m", "in (0, 1] m", 0 < self.range_sigma_m <= 1),
            ("cos_sigma_min", "in (0, 2]", 0 < self.cos_sigma_min <= 2),
            ("cos_sigma_beam", "in [0, 10]", 0 <= self.cos_sigma_beam <= 10),
            ("clutter", "in (0, 1)", 0 < self.clutter < 1),
            ("p_detect", "in [0, 1)", 0 <= self.p_detect < 1),
            ("detect_lo", "in [0, detect_hi)", 0 <= self.detect_lo < self.detect_hi),
            ("detect_hi", "in (detect_lo, 1]", self.detect_lo < self.detect_hi <= 1),
            ("amplitude_sigma", "in [0, 10] (0: off)", 0 <= self.amplitude_sigma <= 10),
            ("max_peaks", "in 1..200", 1 <= self.max_peaks <= 200),
            ("peak_snr", "in [0, 1000]", 0 <= self.peak_snr <= 1000),
            ("echo_bank_oversample", "an integer in 1..8",
             isinstance(self.echo_bank_oversample, int)
             and 1 <= self.echo_bank_oversample <= 8),
        )
        for name, allowed, ok in echo_checks:
            if not ok:
                raise ValueError(f"{name} must be {allowed}, got {getattr(self, name)!r}")
        self.vertical()  # raises naming the field

    @property
    def peaks_read(self) -> int:
        """Heat-map peaks the echo model reads per block (``max_peaks``, doubled with a
        floor)."""
        return self.max_peaks * (2 if self.sonar_height_m is not None else 1)

    def heatmap_sonar(self, sonar: SonarConfig) -> SonarConfig:
        """The sonar settings to make this model's heat maps with: ``sonar`` itself for the
        G models, its bank ``echo_bank_oversample`` times denser for the echo model."""
        if self.model != "echo" or self.echo_bank_oversample == 1:
            return sonar
        return dataclasses.replace(sonar, directions=sonar.directions * self.echo_bank_oversample)

    def vertical(self) -> tuple[FloatArray, FloatArray]:
        """The echo model's floor / ceiling images: vertical offsets ``dz`` (m) and
        reflection products (empty in a 2-D room)."""
        return vertical_images(self.sonar_height_m, self.ceiling_height_m,
                               self.floor_reflection, self.ceiling_reflection,
                               self.vertical_bounces)

    @property
    def ranges_m(self) -> FloatArray:
        """Centres of the range bins, shape (n_r,)."""
        n_r = int(math.floor((self.max_range_m - self.min_range_m) / self.range_step_m))
        return np.asarray(self.min_range_m + self.range_step_m * np.arange(n_r),
                          dtype=np.float64)

    @property
    def angles_rad(self) -> FloatArray:
        """Polar directions relative to the heading, wrapped to (-pi, pi], shape (n_angles,)."""
        a = 2.0 * np.pi * np.arange(self.n_angles) / self.n_angles
        return np.where(a > np.pi, a - 2.0 * np.pi, a)
