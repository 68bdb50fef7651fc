"""Real recordings -> run blocks and odometry, and back (issues 3 and 16). Pure array functions.

Two ways in:

- a stream already at the sonar rate, period-aligned, with the direct wave removed:
  :func:`split_blocks` and :func:`block_odometry` (the ``import-run --wav`` path);
- a **raw** recording from a sound card (any rate >= the sonar rate, unknown latency, its own
  clock, the direct wave and static echoes in it): :func:`import_raw` with
  :class:`RawImportOptions`, which estimates latency and clock offset from the direct path,
  resamples onto the sonar clock, removes the static part (``run``, ``calibration`` or
  ``gated``, see :data:`STATIC_REMOVAL_METHODS`) and reports what it did
  (:class:`RawImportReport`).

And back: :func:`join_blocks`, :func:`pose_log_from_blocks`.

Notes
-----
The clock and geometry conventions are shared with the raw simulator
(:mod:`mapping.simulate.raw`): recording sample ``n`` is taken at sonar time
``n / (fs_rec (1 + clock_offset_ppm 1e-6)) - latency_s``; the loudspeaker starts playing the
transmitted sequence at sonar time 0; pose-log times are on the recording clock. Private
modules: ``_poses`` (pose logs and block odometry), ``_timing`` (direct-path timing),
``_static`` (static removal), ``_raw`` (the raw import), ``_stream`` (the same while
recording: :class:`RawStreamer` hands out each block as soon as its samples are in).
"""

from __future__ import annotations

from mapping.recording._poses import (
    POSE_COLUMNS,
    BlockOdometry,
    PoseLog,
    block_odometry,
    heading_at,
    join_blocks,
    pose_log_from_blocks,
    poses_at,
    split_blocks,
)
from mapping.recording._raw import (
    DEFAULT_TRANSDUCER_OFFSET_M,
    STATIC_REMOVAL_METHODS,
    CalibrationFit,
    RawImportOptions,
    RawImportReport,
    StaticRemoval,
    find_clipping,
    import_raw,
)
from mapping.recording._stream import RawStreamer, StreamBlock
from mapping.recording._timing import ClockFit, fit_clock

__all__ = [
    "DEFAULT_TRANSDUCER_OFFSET_M",
    "POSE_COLUMNS",
    "STATIC_REMOVAL_METHODS",
    "BlockOdometry",
    "CalibrationFit",
    "ClockFit",
    "PoseLog",
    "RawImportOptions",
    "RawImportReport",
    "RawStreamer",
    "StaticRemoval",
    "StreamBlock",
    "block_odometry",
    "find_clipping",
    "fit_clock",
    "heading_at",
    "import_raw",
    "join_blocks",
    "pose_log_from_blocks",
    "poses_at",
    "split_blocks",
]
