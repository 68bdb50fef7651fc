"""Running the service: in this process (``omnisonar serve``) or as a child process.

:func:`serve` runs uvicorn in the foreground. :class:`ServerProcess` starts
``python -m service serve`` as a child on 127.0.0.1 and a free port, waits until it answers,
and stops it (or kills it, to test restarts); the demo, the benchmark and the tests use it.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from types import TracebackType

import httpx

from service.settings import Settings


def serve(maps_dir: Path | None = None, host: str = "127.0.0.1", port: int = 8000,
          log_level: str = "info", insecure: bool = False) -> None:
    """Run the service with uvicorn until interrupted (settings from OMNISONAR_* vars).

    Raises
    ------
    RuntimeError
        ``host`` is not a loopback address and no API keys are configured (and neither
        ``insecure`` nor ``OMNISONAR_ALLOW_INSECURE``): see :mod:`service.auth`.
    """
    import uvicorn

    from service.app import create_app
    from service.auth import KeyRing, check_bind
    from service.slowclients import uvicorn_options

    limit_malloc_arenas(Settings().malloc_arenas)  # before any worker thread allocates
    update: dict[str, object] = {"host": host}
    if maps_dir is not None:
        update["maps_dir"] = maps_dir
    if insecure:
        update["allow_insecure"] = True
    settings = Settings(**update)  # type: ignore[arg-type]
    check_bind(settings, KeyRing.from_settings(settings))
    uvicorn.run(create_app(settings), host=host, port=port, log_level=log_level,
                **uvicorn_options(settings))


def limit_malloc_arenas(n: int) -> bool:
    """Cap glibc's malloc arenas at ``n`` (``mallopt(M_ARENA_MAX, n)``); True when applied.

    glibc gives threads their own arenas (up to 8 per core) and rarely returns their memory:
    with the request threadpool and numba's threads the server's RSS rose 272 -> 886 MiB in
    10 minutes of load (per-minute means 612 -> 845) and was still rising; with 2 arenas
    (``MALLOC_ARENA_MAX=2``, same load, 6 minutes) the per-minute means stayed at 392-416 MiB
    at the same latency. ``n = 0`` or another C library: nothing is changed (False).
    """
    if n <= 0 or not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(-8, int(n)))  # M_ARENA_MAX
    except (OSError, AttributeError):
        return False


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on ``host`` right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


class ServerProcess:
    """``python -m service serve`` as a child process on 127.0.0.1.

    Parameters
    ----------
    maps_dir : Path
        Maps directory (``--maps``); sessions go beside it unless ``env`` says otherwise.
    env : dict, optional
        Extra ``OMNISONAR_*`` variables for the child.
    port : int, optional
        Default: a free port.
    log_path : Path, optional
        Where the child's output goes (default: discarded).
    """

    def __init__(self, maps_dir: Path, env: dict[str, str] | None = None,
                 port: int | None = None, log_path: Path | None = None) -> None:
        self.maps_dir = maps_dir
        self.port = port or free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.env = {**os.environ, **(env or {})}
        self.log_path = log_path
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self, timeout_s: float = 60.0) -> ServerProcess:
        out = open(self.log_path, "ab") if self.log_path else subprocess.DEVNULL  # noqa: SIM115
        cmd = [sys.executable, "-m", "service", "serve", "--maps", str(self.maps_dir),
               "--host", "127.0.0.1", "--port", str(self.port), "--log-level", "warning"]
        self.proc = subprocess.Popen(cmd, env=self.env, stdout=out, stderr=out)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with code {self.proc.returncode}")
            try:
                if httpx.get(f"{self.url}/health", timeout=1.0).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        self.stop()
        raise RuntimeError(f"server did not answer on {self.url} within {timeout_s} s")

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    def kill(self) -> None:
        """SIGKILL: no shutdown hooks, as in a crash."""
        if self.proc is not None and self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGKILL)
            self.proc.wait(10)

    def stop(self) -> None:
        """SIGTERM and wait (SIGKILL after 10 s)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.kill()

    def __enter__(self) -> ServerProcess:
        return self.start()

    def __exit__(self, t: type[BaseException] | None, e: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()


def rss_bytes(pid: int) -> int:
    """Resident set size of process ``pid`` (Linux ``/proc``)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise ValueError(f"no VmRSS for pid {pid}")
