"""Files of real recordings: mono WAV (at the sonar rate, or raw at any rate) and the pose CSV.

Pose CSV: a header row naming at least the columns ``t_s, x_m, y_m, heading_rad, speed_m_s``
(any order, extra columns ignored), then one row per pose, times strictly increasing::

    t_s,x_m,y_m,heading_rad,speed_m_s
    0.0,1.0,1.0,0.785398,0.1
    0.5,1.035,1.035,0.785398,0.1

Errors name the file, the line (1 = header) and the column. WAVs may be 8/16/32-bit PCM
(scaled to [-1, 1)) or 32/64-bit float; they are written as float32. Writes are atomic.
"""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mapping.files._atomic import atomic_write_bytes
from mapping.recording import POSE_COLUMNS, PoseLog


def read_pose_csv(path: str | os.PathLike[str]) -> PoseLog:
    """Read a pose-log CSV; ``ValueError`` naming file, line and column on any problem."""
    path = Path(path)
    text = path.read_text()
    reader = csv.reader(io.StringIO(text))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise ValueError(
            f"{path}: empty file; expected a header {','.join(POSE_COLUMNS)}"
        ) from None
    missing = [c for c in POSE_COLUMNS if c not in header]
    if missing:
        raise ValueError(f"{path}: line 1: missing column(s) {missing}; header is {header}")
    index = {c: header.index(c) for c in POSE_COLUMNS}
    cols: dict[str, list[float]] = {c: [] for c in POSE_COLUMNS}
    for line_no, row in enumerate(reader, start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        for c in POSE_COLUMNS:
            cell = row[index[c]].strip() if index[c] < len(row) else ""
            try:
                value = float(cell)
            except ValueError:
                raise ValueError(
                    f"{path}: line {line_no}: column '{c}': cannot read {cell!r} as a number"
                ) from None
            if not math.isfinite(value):
                raise ValueError(f"{path}: line {line_no}: column '{c}': value {cell!r} "
                                 "must be finite")
            cols[c].append(value)
        t = cols["t_s"]
        if len(t) >= 2 and t[-1] <= t[-2]:
            raise ValueError(f"{path}: line {line_no}: column 't_s': {t[-1]} does not increase "
                             f"on the previous row ({t[-2]})")
    if len(cols["t_s"]) < 2:
        raise ValueError(f"{path}: needs >= 2 pose rows, found {len(cols['t_s'])}")
    return PoseLog(**{c: np.asarray(v, dtype=np.float64) for c, v in cols.items()})


def write_pose_csv(path: str | os.PathLike[str], log: PoseLog) -> Path:
    """Write ``log`` as a pose CSV (full float precision), atomically."""
    path = Path(path)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(POSE_COLUMNS)
    table = np.column_stack([getattr(log, c) for c in POSE_COLUMNS])
    w.writerows([[repr(float(v)) for v in row] for row in table])
    atomic_write_bytes(path, buf.getvalue().encode())
    return path


@dataclass(frozen=True)
class RawWav:
    """A mono WAV as read by :func:`read_wav_raw`: samples (float64, PCM scaled to [-1, 1)),
    the file's rate in Hz, and ``full_scale``: the largest magnitude the format holds
    (``32767 / 32768`` for 16-bit PCM), for clipping detection; None for float WAVs."""

    samples: NDArray[np.float64]
    fs_hz: float
    full_scale: float | None


def read_wav_raw(path: str | os.PathLike[str]) -> RawWav:
    """A mono WAV at any rate, with what clipping detection needs (see :class:`RawWav`)."""
    from scipy.io import wavfile

    path = Path(path)
    try:
        rate, data = wavfile.read(path)
    except FileNotFoundError:
        raise
    except Exception as exc:  # scipy raises ValueError/struct errors on foreign files
        raise ValueError(f"{path}: not a readable WAV file ({exc})") from exc
    if data.ndim != 1:
        raise ValueError(f"{path}: must be mono, has {data.shape[1]} channels")
    if data.dtype == np.uint8:
        return RawWav((data.astype(np.float64) - 128.0) / 128.0, float(rate), 127.0 / 128.0)
    if np.issubdtype(data.dtype, np.integer):
        info = np.iinfo(data.dtype)
        scale = float(-info.min)
        return RawWav(data.astype(np.float64) / scale, float(rate), info.max / scale)
    out = data.astype(np.float64)
    if not np.all(np.isfinite(out)):
        raise ValueError(f"{path}: contains NaN or inf samples")
    return RawWav(out, float(rate), None)


def read_wav_mono(path: str | os.PathLike[str], fs_hz: float) -> NDArray[np.float64]:
    """Samples of a mono WAV recorded at ``fs_hz``, as float64 in [-1, 1] for PCM."""
    wav = read_wav_raw(path)
    if wav.fs_hz != fs_hz:
        raise ValueError(f"{Path(path)}: sample rate must be the sonar rate {fs_hz:g} Hz, "
                         f"got {wav.fs_hz:g} Hz")
    return wav.samples


def write_wav(path: str | os.PathLike[str], samples: NDArray[np.floating], fs_hz: float) -> Path:
    """Write a mono float32 WAV at ``fs_hz`` atomically."""
    from scipy.io import wavfile

    path = Path(path)
    if float(fs_hz) != int(fs_hz):
        raise ValueError(f"fs_hz must be a whole number of Hz for WAV, got {fs_hz}")
    buf = io.BytesIO()
    wavfile.write(buf, int(fs_hz), np.asarray(samples, dtype=np.float32))
    atomic_write_bytes(path, buf.getvalue())
    return path

