"""Access control of the HTTP API: API keys from settings, a principal per request.

Keys come from ``OMNISONAR_API_KEYS`` / ``OMNISONAR_ADMIN_KEYS`` (comma-separated) and from
``OMNISONAR_KEYS_FILE`` (one ``user <key>`` or ``admin <key>`` a line, ``#`` comments). A
client sends its key as ``Authorization: Bearer <key>`` or ``X-API-Key: <key>``.

* **Keys configured**: every route except ``/health`` and the OpenAPI pages needs a key
  (401 without a known one). Sessions belong to the key that created them: another user
  key gets 404, as if the session did not exist (ids are not disclosed). Admin keys may act
  on every session and are the only keys allowed to write maps (upload, build) and read
  build jobs (403 for a user key).
* **No keys** (the default, for a laptop and ``make demo``): the server answers loopback
  clients only, all as one admin principal ``anonymous``; any other client gets 401.
  ``OMNISONAR_ALLOW_INSECURE=true`` lifts that (a trusted network only).

A principal is named by the first 16 hex digits of the SHA-256 of its key: that name, never
the key, is what checkpoints and job records store.
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from fastapi import Depends, Request

from service.errors import ClientError
from service.settings import Settings

#: The principal of every request when no keys are configured.
ANONYMOUS = "anonymous"


@dataclass(frozen=True)
class Principal:
    """Who is calling: a key's short hash (or ``anonymous``) and whether it is an admin."""

    name: str
    admin: bool

    def may_use(self, owner: str) -> bool:
        """May this principal act on something ``owner`` created?"""
        return self.admin or hmac.compare_digest(self.name, owner)


def key_name(key: str) -> str:
    """The stored name of a key: 16 hex digits of its SHA-256 (the key itself is never kept)."""
    return hashlib.sha256(key.encode()).hexdigest()[:16]


class KeyRing:
    """The configured keys, by SHA-256 digest (lookups never compare raw keys)."""

    def __init__(self, users: list[str], admins: list[str]) -> None:
        self._digests: dict[bytes, Principal] = {}
        for key in users:
            self._digests[_digest(key)] = Principal(key_name(key), False)
        for key in admins:
            self._digests[_digest(key)] = Principal(key_name(key), True)

    @classmethod
    def from_settings(cls, cfg: Settings) -> KeyRing:
        """Keys from ``api_keys``, ``admin_keys`` and ``keys_file``; ``ValueError`` on a bad
        keys file line (naming the line number, never the key)."""
        users = _split(cfg.api_keys.get_secret_value())
        admins = _split(cfg.admin_keys.get_secret_value())
        if cfg.keys_file is not None:
            more_users, more_admins = read_keys_file(cfg.keys_file)
            users += more_users
            admins += more_admins
        return cls(users, admins)

    @property
    def enabled(self) -> bool:
        """True when at least one key is configured (keys are then required)."""
        return bool(self._digests)

    def lookup(self, key: str) -> Principal | None:
        return self._digests.get(_digest(key))


def _digest(key: str) -> bytes:
    return hashlib.sha256(key.encode()).digest()


def _split(text: str) -> list[str]:
    return [k.strip() for k in text.split(",") if k.strip()]


#: Shortest key accepted: 16 characters (e.g. ``python -c "import secrets;
#: print(secrets.token_urlsafe(32))"``).
MIN_KEY_CHARS = 16


def read_keys_file(path: Path) -> tuple[list[str], list[str]]:
    """``(user keys, admin keys)`` of a keys file: ``user <key>`` / ``admin <key>`` lines."""
    users: list[str] = []
    admins: list[str] = []
    for n, line in enumerate(path.read_text().splitlines(), start=1):
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        if len(words) != 2 or words[0] not in ("user", "admin"):
            raise ValueError(f"keys file line {n}: expected 'user <key>' or 'admin <key>'")
        if len(words[1]) < MIN_KEY_CHARS:
            raise ValueError(f"keys file line {n}: keys need >= {MIN_KEY_CHARS} characters")
        (admins if words[0] == "admin" else users).append(words[1])
    return users, admins


def is_loopback(host: str | None) -> bool:
    """True for 127.0.0.0/8, ::1 and ``localhost``; also for a peer that is not an IP
    address at all (a Unix socket, an in-process test client): not a network client."""
    if not host or host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return True


def check_bind(cfg: Settings, keys: KeyRing) -> None:
    """Refuse to serve a non-loopback address without keys (unless ``allow_insecure``).

    Raises
    ------
    RuntimeError
        Naming the settings that would make it safe.
    """
    if keys.enabled or cfg.allow_insecure or _bind_is_loopback(cfg.host):
        return
    raise RuntimeError(
        f"refusing to serve {cfg.host!r} without API keys: set OMNISONAR_API_KEYS / "
        "OMNISONAR_ADMIN_KEYS (or OMNISONAR_KEYS_FILE), or OMNISONAR_ALLOW_INSECURE=true "
        "on a trusted network")


def _bind_is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False  # "", a host name: may be reachable from the network


_UNAUTHORIZED = {"WWW-Authenticate": 'Bearer realm="omnisonar"'}


def presented_key(request: Request) -> str | None:
    """The key of ``Authorization: Bearer <key>`` or ``X-API-Key: <key>``, if any."""
    auth = request.headers.get("authorization", "")
    scheme, _, value = auth.partition(" ")
    if scheme.lower() == "bearer" and value.strip():
        return value.strip()
    return request.headers.get("x-api-key") or None


def authenticate(request: Request) -> Principal:
    """The caller, or 401 (a dependency of every protected route)."""
    keys: KeyRing = request.app.state.keys
    cfg: Settings = request.app.state.settings
    if not keys.enabled:
        client = request.client.host if request.client else None
        if cfg.allow_insecure or is_loopback(client):
            return Principal(ANONYMOUS, True)
        raise ClientError(401, "unauthorized", "no API keys are configured: this server "
                          "answers loopback clients only", "authorization",
                          "set OMNISONAR_API_KEYS on the server", headers=_UNAUTHORIZED)
    key = presented_key(request)
    principal = None if key is None else keys.lookup(key)
    if principal is None:
        detail = "missing API key" if key is None else "unknown API key"
        raise ClientError(401, "unauthorized", detail, "authorization",
                          "Authorization: Bearer <key> or X-API-Key: <key>",
                          headers=_UNAUTHORIZED)
    return principal


def require_admin(principal: Annotated[Principal, Depends(authenticate)]) -> Principal:
    """The caller if it holds an admin key, else 403."""
    if not principal.admin:
        raise ClientError(403, "forbidden", "this operation needs an admin key",
                          "authorization", "a key from OMNISONAR_ADMIN_KEYS")
    return principal


Caller = Annotated[Principal, Depends(authenticate)]
Admin = Annotated[Principal, Depends(require_admin)]
