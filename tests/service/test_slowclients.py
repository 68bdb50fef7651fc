"""Slow and half-sent requests against a real uvicorn process on 127.0.0.1 (issue 17).

The defect: 900 half-sent requests stayed open > 65 s, because uvicorn has no limit on how
long a client may take to send a request's headers. Here the server runs with
``OMNISONAR_READ_TIMEOUT_S`` = 2 s; 80 sockets send part of a request line or of the headers
(half of them then stall, half keep trickling a header byte every 0.3 s, which must not
extend the deadline), and each must be closed by the server within the deadline plus a
generous margin, while a well-formed request is still answered. A body that trickles in
after complete headers is cut with the documented 408.

The only wall-time assertions are the deadline itself: closed no earlier than 0.75 x the
deadline (not by something else) and no later than the deadline + 8 s (a loaded machine).
"""

from __future__ import annotations

import contextlib
import json
import selectors
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from mapping.files import write_map
from service.server import ServerProcess
from tests.service.helpers import raster_map

DEADLINE_S = 2.0
MARGIN_S = 8.0
N_SOCKETS = 80
TRICKLE_S = 0.3

#: request heads cut short: in the request line, in the headers, just before the blank line
PARTIAL_HEADS = (b"GET /hea",
                 b"POST /sessions HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Ty",
                 b"GET /maps HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Pad: ")


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    maps = tmp_path_factory.mktemp("slowclients") / "maps"
    write_map(maps / "room.npz", raster_map())
    env = {"OMNISONAR_DEFAULT_MAP": "false", "OMNISONAR_READ_TIMEOUT_S": str(DEADLINE_S)}
    with ServerProcess(maps, env=env) as srv:
        yield srv


def _address(srv: ServerProcess) -> tuple[str, int]:
    return "127.0.0.1", srv.port


def _closed_by_peer(sock: socket.socket) -> bool:
    """Drain what the server sent; True once it closed the connection."""
    try:
        return sock.recv(65536) == b""
    except (ConnectionResetError, BrokenPipeError):
        return True
    except BlockingIOError:
        return False


@pytest.mark.slow
def test_half_sent_requests_are_closed_at_the_deadline(server: ServerProcess) -> None:
    opened: dict[socket.socket, float] = {}
    trickling: list[socket.socket] = []
    for i in range(N_SOCKETS):
        sock = socket.create_connection(_address(server), timeout=5)
        opened[sock] = time.monotonic()
        sock.sendall(PARTIAL_HEADS[i % len(PARTIAL_HEADS)])
        sock.setblocking(False)
        if i % 2:
            trickling.append(sock)
    sel = selectors.DefaultSelector()
    for sock in opened:
        sel.register(sock, selectors.EVENT_READ, sock)
    closed: dict[socket.socket, float] = {}
    normal: list[int] = []
    give_up = time.monotonic() + DEADLINE_S + MARGIN_S
    next_trickle = time.monotonic() + TRICKLE_S
    try:
        while len(closed) < len(opened) and time.monotonic() < give_up:
            if not normal:  # a well-formed request while all 80 are held open
                with httpx.Client(base_url=server.url, timeout=10) as http:
                    normal += [http.get("/health").status_code,
                               http.get("/maps/room").status_code]
            for key, _ in sel.select(timeout=0.05):
                sock = key.data
                if _closed_by_peer(sock):
                    closed[sock] = time.monotonic()
                    sel.unregister(sock)
            if time.monotonic() >= next_trickle:
                next_trickle += TRICKLE_S
                for sock in trickling:
                    if sock not in closed:
                        # a socket the server already closed: the selector reports it
                        with contextlib.suppress(OSError):
                            sock.send(b"a")
    finally:
        sel.close()
        for sock in opened:
            sock.close()
    assert normal == [200, 200]
    assert len(closed) == N_SOCKETS, (
        f"{N_SOCKETS - len(closed)} of {N_SOCKETS} half-sent requests still open "
        f"{DEADLINE_S + MARGIN_S:g} s after they started (deadline {DEADLINE_S:g} s)")
    held = sorted(closed[s] - opened[s] for s in closed)
    assert held[0] >= 0.75 * DEADLINE_S, held  # the deadline closed them, nothing earlier
    assert held[-1] <= DEADLINE_S + MARGIN_S, held


def _read_response(sock: socket.socket, until: float) -> bytes:
    """Everything the server sends until it closes the connection (or ``until``)."""
    data = b""
    while time.monotonic() < until:
        sock.settimeout(max(0.01, min(TRICKLE_S, until - time.monotonic())))
        try:
            chunk = sock.recv(65536)
        except TimeoutError:
            continue
        if not chunk:
            break
        data += chunk
    return data


@pytest.mark.slow
@pytest.mark.parametrize("trickle", [False, True], ids=["stalled", "trickling"])
def test_slow_body_is_cut_with_408(server: ServerProcess, trickle: bool) -> None:
    """Complete headers, then a body that stalls or arrives a byte every 0.3 s: 408 with the
    documented error body, within the deadline, and the connection closed."""
    body = json.dumps({"map_id": "room", "particles": 300, "pad": "x" * 400}).encode()
    with socket.create_connection(_address(server), timeout=5) as sock:
        sock.sendall(b"POST /sessions HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                     b"Content-Type: application/json\r\n"
                     b"Content-Length: " + str(len(body)).encode() + b"\r\n\r\n" + body[:10])
        start = time.monotonic()
        give_up = start + DEADLINE_S + MARGIN_S
        sent, data = 10, b""
        while trickle and not data and time.monotonic() < give_up and sent < len(body):
            try:
                sock.sendall(body[sent:sent + 1])
            except OSError:
                break  # the server closed the connection: read what it said
            sent += 1
            data = _read_response(sock, time.monotonic() + TRICKLE_S)
        data += _read_response(sock, give_up)
        took = time.monotonic() - start
    head, _, payload = data.partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 408"), (data[:300], took, sent)
    assert b"connection: close" in head.lower()
    err = json.loads(payload)
    assert err["error"] == "timeout" and err["field"] == "body", err
    assert sent < len(body)  # cut before the body was complete
    assert 0.75 * DEADLINE_S <= took <= DEADLINE_S + MARGIN_S, took


def test_options_carry_the_header_deadline(tmp_path: Path) -> None:
    """The options ``omnisonar serve`` passes to uvicorn use the deadline protocol with
    ``OMNISONAR_READ_TIMEOUT_S`` (the real-process tests above depend on it)."""
    from service.settings import Settings
    from service.slowclients import HeaderDeadlineH11, uvicorn_options

    opts = uvicorn_options(Settings(maps_dir=tmp_path, read_timeout_s=7.5))
    assert issubclass(opts["http"], HeaderDeadlineH11)
    assert opts["http"].header_timeout_s == 7.5
