"""Simulated raw recordings: what a real robot's sound card records (issue 16, item 2).

The image-source engine (:mod:`mapping.simulate.ism`) gives the clean stream the heat map
wants: wall echoes at the sonar rate, sample 0 on a period boundary, no direct wave. A real
recording differs; :func:`simulate_raw` adds each difference on request (:class:`RawConfig`,
every effect off by default so tests can switch one on at a time) and returns a
:class:`RawRecording` with a pose log and the ground truth. :func:`iter_raw_chunks` is the
same as a generator (:func:`assemble_raw` joins its chunks). The signal to play through the
loudspeaker is :func:`mapping.signal.playback_signal`.

Conventions (shared with the raw importer, :mod:`mapping.recording`)
--------------------------------------------------------------------
Two clocks. *Sonar time* ``tau`` is the clean simulator's and the run files' clock: sample
``j`` of the transmitted sequence leaves the loudspeaker at ``tau = j / fs`` (fs of the
``SonarConfig``), the trajectory is a function of ``tau``, and the playback clock is the
sonar clock (the loudspeaker plays :func:`~mapping.signal.transmitted_at` at its own rate).
The *recording clock* is the sound card's: its sample ``n`` is taken at sonar time

    tau_n = n / (fs_rec (1 + clock_offset_ppm 1e-6)) - latency_s,

``latency_s >= 0`` being the time from the first recorded sample to the start of playback
and a positive ``clock_offset_ppm`` a recording clock running fast. Samples with
``tau_n < 0`` precede the playback and hold noise only. From ``tau = 0`` on the field is the
steady (periodic) one: the start-up transient, when echoes of samples sent before the onset
are still missing, is not modelled (the importer discards at least a period after the onset).
The pose log is on the recording clock: a pose at sonar time ``tau`` is logged at
``t_rec = (tau + latency_s) (1 + clock_offset_ppm 1e-6)``.

Geometry. Loudspeaker and microphone sit ``transducer_offset_m`` apart about the robot's
pose. Wall echoes are still rendered monostatic from that centre: the bistatic path is longer
by about ``offset^2 / (8 r)`` (under 1 mm for 5 cm at 1 m), which is neglected. The direct
wave has delay ``offset / c``, amplitude ``1 / offset`` (3-D spreading) and no Doppler (it
rides with the robot). In a room of ceiling height ``H`` with the sonar at height ``h`` the
floor and ceiling images sit at vertical path lengths ``dz = 2h`` (floor), ``2 (H - h)``
(ceiling), ``2H`` (floor and ceiling), ...: alone they give constant delays
``sqrt(dz^2 + offset^2) / c`` with zero Doppler; combined with a wall path of 2-D delay
``tau2`` (``vertical_order = 2``) the delay is ``sqrt(tau2^2 + (dz / c)^2)`` with 3-D
spreading ``1 / (c tau)``, keeping the wall path's Doppler and validity (walls are infinitely
tall). Edge-diffracted paths are not combined with the floor and ceiling.

Signal chain. At the sonar rate: wall echoes + their floor/ceiling combinations + direct wave +
pure vertical bounces, silent before ``tau = 0``; the loudspeaker's then the microphone's
band-pass (causal Butterworth, state kept over the whole stream; both act on the received
sum, which differs from filtering before the Doppler shift by a frequency error of v/c ~ 3e-4,
neglected). Then :func:`mapping.resample.resample_at` reads the stream at the ``tau_n``
(low-pass at half the lower rate), samples before the onset are zeroed, white noise is added
(``snr_db`` against the wall-echo power per sonar sample, i.e. the clean simulator's SNR:
direct wave and floor/ceiling excluded; its variance scaled by ``fs_rec / fs`` so the noise
density in the sonar band is the clean run's), and the sum clipped to ``full_scale``.
Temperature changes the propagation speed (:func:`mapping.signal.sound_speed_at`) while the
processing keeps the ``SonarConfig``'s.

Notes
-----
Private modules: ``_config`` (:class:`RawConfig`), ``_paths`` (floor and ceiling images, the
static paths, the 3-D lift of a planned stretch, the band-passes), ``_stream`` (the chunked
signal chain, the pose log, the records).
"""

from __future__ import annotations

from mapping.simulate.raw._config import FS_RANGE_HZ, RawConfig
from mapping.simulate.raw._paths import band_sos, static_paths, vertical_images, vertical_plan
from mapping.simulate.raw._stream import (
    RawChunk,
    RawRecording,
    RawTruth,
    assemble_raw,
    iter_raw_chunks,
    pose_log,
    propagation_speed,
    recording_times,
    resample_cutoff_hz,
    simulate_raw,
)

__all__ = [
    "FS_RANGE_HZ",
    "RawChunk",
    "RawConfig",
    "RawRecording",
    "RawTruth",
    "assemble_raw",
    "band_sos",
    "iter_raw_chunks",
    "pose_log",
    "propagation_speed",
    "recording_times",
    "resample_cutoff_hz",
    "simulate_raw",
    "static_paths",
    "vertical_images",
    "vertical_plan",
]
