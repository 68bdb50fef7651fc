"""``omnisonar stream``: the robot's side of the localization service (issue 16, item 4).

Reads a raw microphone recording (a WAV file, played back at real-time pace, or raw PCM on
stdin as a sound card delivers it), cuts it into sonar blocks as the samples arrive
(:class:`mapping.recording.RawStreamer`: clock fitted on the direct path after a warm-up,
resampled onto the sonar clock, static part removed), reads the odometry of each block from a
pose CSV on the recording's clock, POSTs block and odometry to a running service
(``omnisonar serve``) and prints the pose it answers. What a user adapts for their robot:
replace the WAV / stdin by the sound card and the CSV by the wheel odometry.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np

from service.commands.runs import _load_config, add_raw_import_options, raw_import_options

if TYPE_CHECKING:
    from mapping.recording import PoseLog, RawStreamer
    from mapping.signal import SonarConfig

#: PCM sample formats accepted on stdin: numpy dtype and full scale.
PCM_FORMATS = {"s16le": ("<i2", 32768.0), "s32le": ("<i4", 2147483648.0),
               "f32le": ("<f4", 1.0)}


def add_stream(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("stream", help="robot side: raw recording + odometry -> POST blocks to a "
                       "running service, print poses")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--wav", help="raw recording to play back (any rate >= the sonar rate)")
    src.add_argument("--stdin", action="store_true",
                     help="read raw mono PCM from stdin (e.g. arecord -t raw -f S16_LE ...)")
    p.add_argument("--rate", type=float, help="stdin sample rate in Hz (with --stdin)")
    p.add_argument("--format", choices=sorted(PCM_FORMATS), default="s16le",
                   help="stdin sample format")
    p.add_argument("--poses", required=True, help="odometry CSV t_s,x_m,y_m,heading_rad,"
                   "speed_m_s on the recording's clock (first sample = 0 s)")
    p.add_argument("--url", default="http://127.0.0.1:8000", help="the service")
    p.add_argument("--map", default="default",
                   help="map id on the service (%(default)s: the map it builds at start)")
    p.add_argument("--particles", type=int, default=2000, help="particle filter size")
    p.add_argument("--global", dest="global_", action="store_true",
                   help="start unknown (global); default: at the first block's logged pose")
    p.add_argument("--pace", type=float, default=1.0,
                   help="--wav playback speed: 1 = real time, 0 = as fast as possible")
    p.add_argument("--chunk-ms", type=float, default=100.0, help="samples read per chunk")
    p.add_argument("--warmup", type=float, default=3.0,
                   help="seconds recorded before the clock is fitted on the direct path")
    p.add_argument("--json", action="store_true", help="one JSON object per block")
    p.add_argument("--config", help="SonarConfig JSON file (default: paper Table 1)")
    add_raw_import_options(p.add_argument_group("raw import (as import-run --raw)"))
    p.set_defaults(func=_cmd_stream)


def _chunks_wav(path: str, chunk_ms: float, pace: float) -> tuple[float, float | None,
                                                                   Iterator[np.ndarray]]:
    from mapping.files import read_wav_raw

    wav = read_wav_raw(path)
    n = max(int(wav.fs_hz * chunk_ms / 1000.0), 1)

    def gen() -> Iterator[np.ndarray]:
        t0 = time.monotonic()
        for i in range(0, wav.samples.size, n):
            if pace > 0:  # the sound card delivers chunk i once it is recorded
                wait = (i + n) / wav.fs_hz / pace - (time.monotonic() - t0)
                if wait > 0:
                    time.sleep(wait)
            yield wav.samples[i:i + n]

    return wav.fs_hz, wav.full_scale, gen()


def _chunks_stdin(stream: BinaryIO, rate: float, fmt: str, chunk_ms: float
                  ) -> Iterator[np.ndarray]:
    dtype, scale = PCM_FORMATS[fmt]
    width = np.dtype(dtype).itemsize
    n = max(int(rate * chunk_ms / 1000.0), 1) * width
    rest = b""
    while True:
        data = stream.read(n)
        if not data:
            return
        data = rest + data
        cut = len(data) - len(data) % width
        rest = data[cut:]
        yield np.frombuffer(data[:cut], dtype=dtype).astype(np.float64) / scale


def _cmd_stream(args: argparse.Namespace, http: Any = None, stdin: BinaryIO | None = None
                ) -> int:
    """The command; ``http`` (an ``httpx.Client``-like object with the service's base URL)
    and ``stdin`` are for tests."""
    import httpx

    from mapping.files import read_pose_csv
    from mapping.recording import RawStreamer

    if args.stdin and args.rate is None:
        raise ValueError("--stdin needs --rate (the sound card's sample rate in Hz)")
    if not (math.isfinite(args.pace) and args.pace >= 0):
        raise ValueError(f"--pace must be >= 0, got {args.pace}")
    if not 1.0 <= args.chunk_ms <= 5000.0:
        raise ValueError(f"--chunk-ms must be in [1, 5000], got {args.chunk_ms}")
    config = _load_config(args.config)
    options, calibration = raw_import_options(args)
    log = read_pose_csv(args.poses)
    if args.wav:
        fs, _, chunks = _chunks_wav(args.wav, args.chunk_ms, args.pace)
    else:
        fs = float(args.rate)
        chunks = _chunks_stdin(stdin or sys.stdin.buffer, fs, args.format, args.chunk_ms)
    streamer = RawStreamer(fs, config, options, calibration, warmup_s=args.warmup)
    own = http is None
    client = httpx.Client(base_url=args.url, timeout=60.0) if own else http
    if not args.json:
        print("  seq    t_s       x       y     yaw  status      sd_m   log_err_m")
    try:
        _stream_blocks(args, config, log, streamer, chunks, client)
    except httpx.HTTPStatusError as exc:
        raise ValueError(f"the service at {args.url} answered {exc.response.status_code}: "
                         f"{exc.response.text[:300]}") from None
    except httpx.HTTPError as exc:
        raise ValueError(f"the service at {args.url}: {exc} (is `omnisonar serve` running "
                         "there?)") from None
    finally:
        if own:
            client.close()
    return 0


def _stream_blocks(args: argparse.Namespace, config: SonarConfig, log: PoseLog,
                   streamer: RawStreamer, chunks: Iterator[np.ndarray], client: Any) -> None:
    """Push every chunk, POST every block that comes out, print the answers; the session is
    closed at the end (also on an error)."""
    from mapping.recording import block_odometry, poses_at

    options = streamer.options
    sid: str | None = None
    try:
        for chunk in chunks:
            for blk in streamer.push(chunk):
                t = np.array([blk.start_rec_s + 0.5 * blk.duration_rec_s])
                if not log.t_s[0] <= t[0] <= log.t_s[-1]:
                    continue  # no odometry for this block
                odo = block_odometry(log, 1, blk.duration_rec_s, np.array([blk.start_rec_s]))
                if sid is None:
                    x, y, yaw = (float(v) for v in odo.pose[0])
                    start = None if args.global_ else (x, y, yaw)
                    sid = _open(client, args, start, streamer.config.sound_speed_m_s
                                if options.temperature_c is not None
                                or options.sound_speed_m_s is not None else None)
                r = client.post(
                    f"/sessions/{sid}/blocks",
                    params={"seq": blk.index, "fs_hz": config.fs_hz,
                            "speed_m_s": float(odo.speed_m_s[0]),
                            "yaw_rate_rad_s": float(odo.yaw_rate_rad_s[0])},
                    content=blk.samples.astype("<f4").tobytes(),
                    headers={"content-type": "application/octet-stream"})
                r.raise_for_status()
                _print(args, blk.index, float(t[0]), r.json(), poses_at(log, t)[0])
    finally:
        if sid is not None:
            client.delete(f"/sessions/{sid}")
    if sid is None:
        raise ValueError("no block was cut from the recording: too short, or no pose for it")


def _open(client: Any, args: argparse.Namespace, start: tuple[float, float, float] | None,
          sound_speed_m_s: float | None) -> str:
    """The session; with ``--temperature`` the service processes the blocks at the air's
    speed of sound too (not only the import's timing), with the heights its echo model
    predicts the floor / ceiling copies of every wall echo."""
    from service.client_example import open_session

    return open_session(client, args.map, args.particles, 0, start,
                        sound_speed_m_s=sound_speed_m_s,
                        heights_m=(args.sonar_height, args.ceiling_height))


def _print(args: argparse.Namespace, seq: int, t_s: float, est: dict[str, Any],
           logged: np.ndarray) -> None:
    from mapping.angles import pose_error

    p = est["pose"]
    err_m, _ = pose_error(np.array([p["x"], p["y"], p["yaw"]]), logged)
    cov = est.get("covariance")
    sd = math.sqrt(max(cov[0][0] + cov[1][1], 0.0)) if cov else math.nan
    status = est.get("status", "converged" if est.get("converged") else "uncertain")
    if args.json:
        print(json.dumps({"seq": seq, "t_s": t_s, "pose": p, "status": status,
                          "sd_m": sd if math.isfinite(sd) else None,
                          "log_error_m": float(err_m)}), flush=True)
        return
    print(f"{seq:5d} {t_s:7.2f} {p['x']:7.3f} {p['y']:7.3f} {p['yaw']:7.3f}  {status:10s} "
          f"{sd:6.3f}  {err_m:8.3f}", flush=True)
