"""Live localization sessions: one filter each, a lock each, checkpointed per a policy.

The store holds sessions in memory and mirrors each to ``<sessions_dir>/<id>.npz`` (written
atomically: temporary name, fsync, rename) after creation and, under the default
:class:`CheckpointPolicy`, after every committed block, so a killed server restarts with
every session at its last committed block. A block is then committed only when the filter
update succeeded *and* its checkpoint is on disk; on any failure the in-memory filter is
restored from the snapshot taken before the update, so a rejected request leaves the
session exactly as it was. A lighter policy (every N blocks, every T seconds) trades the
last few blocks after a crash for throughput; a graceful shutdown (:meth:`SessionStore.flush`)
loses nothing under any policy.

Watchers (the live view) subscribe to a session through :attr:`SessionStore.live`; a
committed block is published to them, and costs one dict lookup when nobody watches.

Nothing here computes a pose: the :class:`Tracker` behind each session
(:class:`service.localizer.Localizer`; a test double in the tests) calls ``mapping`` and
``localization`` and returns the core's :class:`~localization.estimate.PoseEstimate`, which
the store keeps as it is (the HTTP layer converts it once, into its response model).
"""

from __future__ import annotations

import io
import json
import math
import os
import secrets
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from localization.estimate import Mode, PoseEstimate
from mapping.files import atomic_write_bytes
from mapping.signal import SonarConfig
from service.live import Broadcaster

#: Written by this version; format 1 (the service's flat estimate) still loads.
SESSION_FORMAT = "omnisonar-session-2"
SESSION_FORMATS = ("omnisonar-session-1", SESSION_FORMAT)


# ---- what a session is made of ------------------------------------------------------------
@dataclass(frozen=True)
class FilterSpec:
    """What a session asked for at creation."""

    kind: str = "pf"
    particles: int = 2000
    seed: int = 0
    initial_pose: tuple[float, float, float] | None = None
    initial_covariance: tuple[tuple[float, ...], ...] | None = None  # None: the core's default
    beta: float | None = None       # sensor sharpness; None: the server's default
    map_sha256: str | None = None   # content hash of the map the session runs on (issue 17)
    sound_speed_m_s: float | None = None  # the session's air; None: the map's (issue 16)
    sonar_height_m: float | None = None   # floor / ceiling for the echo model (issue 16)
    ceiling_height_m: float | None = None
    open_map: str = "uncertain"  # FilterConfig.open_map_global (issue 14)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FilterSpec:
        pose = d.get("initial_pose")
        cov = d.get("initial_covariance")
        return cls(
            kind=str(d["kind"]), particles=int(d["particles"]), seed=int(d["seed"]),
            initial_pose=None if pose is None else (float(pose[0]), float(pose[1]),
                                                     float(pose[2])),
            initial_covariance=None if cov is None else tuple(tuple(map(float, r)) for r in cov),
            beta=None if d.get("beta") is None else float(d["beta"]),
            map_sha256=None if d.get("map_sha256") is None else str(d["map_sha256"]),
            sound_speed_m_s=_opt_float(d, "sound_speed_m_s"),
            sonar_height_m=_opt_float(d, "sonar_height_m"),
            ceiling_height_m=_opt_float(d, "ceiling_height_m"),
            open_map=str(d.get("open_map", "uncertain")),
        )


def _opt_float(d: dict[str, Any], key: str) -> float | None:
    """``d[key]`` as a float, None when absent (older checkpoints) or null."""
    return None if d.get(key) is None else float(d[key])


@dataclass(frozen=True)
class BlockInput:
    """One validated block: samples (B,) float64 (empty: predict only) and its odometry."""

    seq: int
    samples: NDArray[np.float64]
    speed_m_s: float
    yaw_rate_rad_s: float
    dt_s: float = 0.0  # set by the store: previous committed block's midpoint to this one's


#: Longest odometry step passed to a filter (localization.motion accepts dt <= 60 s).
MAX_STEP_S = 60.0


def block_dt_s(seq: int, last_seq: int | None, block_s: float) -> float:
    """Time from the previous committed block's midpoint to block ``seq``'s (0 at first).

    A gap in ``seq`` (lost blocks) lengthens the step; it is capped at :data:`MAX_STEP_S`.
    """
    if last_seq is None:
        return 0.0
    return min(float(seq - last_seq) * block_s, MAX_STEP_S)


class Tracker(Protocol):
    """One live filter on one map."""

    config: SonarConfig

    def update(self, block: BlockInput) -> PoseEstimate:
        """Step the filter by one block; ``ValueError`` for a block it rejects."""
        ...

    def reinit_global(self) -> None: ...

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: dict[str, Any]) -> None: ...

    def particles(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """``(poses (n, 3), weights (n,))`` or None when the filter has no particles."""
        ...


class TrackerFactory(Protocol):
    """Makes trackers on stored maps; :class:`InvalidSpec` for a spec the filter refuses."""

    def create(self, map_id: str, spec: FilterSpec) -> Tracker: ...

    def restore(self, map_id: str, spec: FilterSpec, state: dict[str, Any]) -> Tracker: ...


# ---- errors -------------------------------------------------------------------------------
class InvalidSpec(ValueError):
    """A session spec the filter refuses (422), naming the request field at fault."""

    def __init__(self, field: str, detail: str, allowed: str | None = None) -> None:
        super().__init__(detail)
        self.field, self.allowed = field, allowed


class SessionNotFound(KeyError):
    """No session with this id (404)."""


class SessionConflict(Exception):
    """A sequence number that is not after the last committed one (409)."""

    def __init__(self, seq: int, last_seq: int | None) -> None:
        super().__init__(f"seq {seq} is not after the last committed seq {last_seq}")
        self.seq = seq
        self.last_seq = last_seq


class SessionLimit(Exception):
    """The cap on concurrent sessions is reached (429)."""


class MapChanged(ValueError):
    """The map a session is pinned to (by content hash) was overwritten or removed."""

    def __init__(self, map_id: str, detail: str) -> None:
        super().__init__(detail)
        self.map_id = map_id


class SessionRefused(Exception):
    """A checkpointed session not restored because its map changed (409 to its owner)."""

    def __init__(self, session_id: str, owner: str, detail: str) -> None:
        super().__init__(detail)
        self.session_id, self.owner = session_id, owner


@dataclass
class Session:
    """One live filter and its bookkeeping; mutate only while holding ``lock``."""

    id: str
    map_id: str
    spec: FilterSpec
    tracker: Tracker
    created_at: float
    last_active_at: float
    last_seq: int | None = None
    n_updates: int = 0
    estimate: PoseEstimate | None = None  # after the last committed block (None: none yet)
    processing_ms: float = 0.0            # server time of that update
    owner: str = ""                       # name of the API key that created it (service.auth)
    pending: int = 0                      # committed blocks not in the checkpoint yet
    checkpointed_at: float = 0.0          # clock time of the last checkpoint written
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def meta(self) -> dict[str, Any]:
        """JSON-able bookkeeping (everything but the filter state)."""
        return {
            "id": self.id,
            "map_id": self.map_id,
            "owner": self.owner,
            "spec": self.spec.to_dict(),
            "created_at": self.created_at,
            "last_active_at": self.last_active_at,
            "last_seq": self.last_seq,
            "n_updates": self.n_updates,
            "estimate": None if self.estimate is None else {
                **estimate_to_json(self.estimate), "processing_ms": self.processing_ms},
        }


def _floats(a: Any) -> Any:
    return np.asarray(a, dtype=np.float64).tolist()


def estimate_to_json(est: PoseEstimate) -> dict[str, Any]:
    """Every field of a :class:`PoseEstimate` as JSON values (floats round-trip exactly)."""
    return {
        "pose": _floats(est.pose), "cov": _floats(est.cov),
        "mean_all": _floats(est.mean_all), "cov_all": _floats(est.cov_all),
        "modes": [{"weight": float(m.weight), "mean": _floats(m.mean), "cov": _floats(m.cov)}
                  for m in est.modes],
        "ess": float(est.ess), "converged": bool(est.converged),
        "direction_observable": bool(est.direction_observable), "updated": bool(est.updated),
        "model": str(est.model), "likelihood_scale": float(est.likelihood_scale),
        "status": str(est.status), "fit": None if math.isnan(est.fit) else float(est.fit),
        "covered": bool(est.covered), "refined": bool(est.refined),
        "reckoned": bool(est.reckoned), "reason": str(est.reason),
    }


def estimate_from_json(d: dict[str, Any]) -> PoseEstimate:
    """Inverse of :func:`estimate_to_json`; also reads format 1's flat estimate (``pose``,
    ``covariance``, ``modes`` as ``[x, y, yaw, weight]``, ``extra``), which kept neither the
    modes' covariances nor the mean of the whole set: those come back as NaN and the best
    mode's mean (neither is reported)."""

    def arr(v: Any) -> NDArray[np.float64]:
        return np.array(v, dtype=np.float64)

    if "mean_all" in d:
        modes = tuple(Mode(weight=float(m["weight"]), mean=arr(m["mean"]), cov=arr(m["cov"]))
                      for m in d["modes"])
        return PoseEstimate(
            pose=arr(d["pose"]), cov=arr(d["cov"]), mean_all=arr(d["mean_all"]),
            cov_all=arr(d["cov_all"]), modes=modes, ess=float(d["ess"]),
            converged=bool(d["converged"]), direction_observable=bool(d["direction_observable"]),
            updated=bool(d["updated"]), model=str(d["model"]),
            likelihood_scale=float(d["likelihood_scale"]),
            status=str(d.get("status", "converged" if d["converged"] else "uncertain")),
            fit=math.nan if d.get("fit") is None else float(d["fit"]),
            covered=bool(d.get("covered", True)), refined=bool(d.get("refined", False)),
            reckoned=bool(d.get("reckoned", False)), reason=str(d.get("reason", "")))
    extra = d.get("extra", {})
    cov = arr(d["covariance"])
    return PoseEstimate(
        pose=arr(d["pose"]), cov=cov, mean_all=arr(d["pose"]),
        cov_all=cov if d.get("covariance_all") is None else arr(d["covariance_all"]),
        modes=tuple(Mode(weight=float(m[3]), mean=arr(m[:3]), cov=np.full((3, 3), math.nan))
                    for m in d["modes"]),
        ess=float(d["ess"]), converged=bool(d["converged"]),
        direction_observable=bool(d["direction_observable"]),
        updated=bool(extra.get("updated", True)), model=str(extra.get("model", "correlation")),
        likelihood_scale=float(extra.get("likelihood_scale", 1.0)),
        status="converged" if d["converged"] else "uncertain")


def _check_finite(est: PoseEstimate) -> None:
    values = np.concatenate([np.ravel(est.pose), np.ravel(est.cov), np.ravel(est.cov_all),
                             [est.ess]])
    if not np.all(np.isfinite(values)):
        # a numerical failure of the filter, not of the input: the store rolls the session
        # back and the client gets a 500 naming it (JSON cannot carry NaN anyway)
        raise FloatingPointError("the filter produced a non-finite estimate")


# ---- checkpoint encoding ------------------------------------------------------------------
def flatten_state(state: dict[str, Any]) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
    """Split a nested state dict into ``.npz`` arrays and a JSON-able remainder.

    Arrays go under ``"state/<path>"`` keys; everything else stays in the returned dict with
    each array replaced by the marker ``{"__array__": "<key>"}``.
    """
    arrays: dict[str, NDArray[Any]] = {}

    def walk(obj: Any, path: str) -> Any:
        if isinstance(obj, np.ndarray):
            key = f"state/{path}"
            arrays[key] = obj
            return {"__array__": key}
        if isinstance(obj, dict):
            return {str(k): walk(v, f"{path}.{k}" if path else str(k)) for k, v in obj.items()}
        if isinstance(obj, list | tuple):
            return [walk(v, f"{path}.{i}") for i, v in enumerate(obj)]
        if isinstance(obj, np.generic):
            return obj.item()
        return obj

    return arrays, walk(state, "")


def unflatten_state(tree: Any, arrays: dict[str, NDArray[Any]]) -> Any:
    """Inverse of :func:`flatten_state`."""
    if isinstance(tree, dict):
        if set(tree) == {"__array__"}:
            return arrays[tree["__array__"]]
        return {k: unflatten_state(v, arrays) for k, v in tree.items()}
    if isinstance(tree, list):
        return [unflatten_state(v, arrays) for v in tree]
    return tree


def write_checkpoint(path: Path, session: Session, fsync: bool = True) -> None:
    """Write ``session`` (bookkeeping + filter state) atomically to ``path``.

    Always a temporary file renamed over the old one, so a killed process leaves either the
    old or the new checkpoint. ``fsync`` also survives power loss (costs a disk flush). The
    ``.npz`` is built in memory and written at once: ``np.savez`` straight to the file makes
    many small writes and seeks (~0.5 ms more per block).
    """
    arrays, tree = flatten_state(session.tracker.state_dict())
    payload: dict[str, Any] = {
        "format": np.array(SESSION_FORMAT),
        "meta": np.array(json.dumps(session.meta())),
        "state": np.array(json.dumps(tree)),
        **arrays,
    }
    buf = io.BytesIO()
    np.savez(buf, **payload)
    atomic_write_bytes(path, buf.getvalue(), fsync=fsync)


@dataclass(frozen=True)
class CheckpointPolicy:
    """When the store writes a session's checkpoint after a committed block.

    Attributes
    ----------
    every_blocks : int
        Write when this many committed blocks are not in the checkpoint yet: 1 (the default)
        writes after every block, so a crash loses nothing committed; 0 never writes by count.
    every_s : float
        Also write when the last checkpoint is older than this many seconds, at the next
        block or at the store's periodic sweep (:meth:`SessionStore.expire`); 0: never by
        time. A crash loses at most ``every_blocks - 1`` blocks or ``every_s`` seconds.
    fsync : bool
        Flush each checkpoint to disk: survives power loss, not only a killed process.
    """

    every_blocks: int = 1
    every_s: float = 0.0
    fsync: bool = True

    def __post_init__(self) -> None:
        if self.every_blocks < 0 or not self.every_s >= 0:
            raise ValueError("checkpoint every_blocks and every_s must be >= 0")

    def due(self, pending: int, age_s: float) -> bool:
        """Is a checkpoint due with ``pending`` unsaved blocks, the last one ``age_s`` old?"""
        if pending <= 0:
            return False
        return (0 < self.every_blocks <= pending) or (0 < self.every_s <= age_s)


def read_checkpoint(path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(meta, state)`` of a checkpoint; ``ValueError`` if the file is not one."""
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
    except Exception as exc:
        raise ValueError(f"{path}: not a readable session checkpoint ({exc})") from exc
    if str(data.get("format", "")) not in SESSION_FORMATS:
        raise ValueError(f"{path}: key 'format' must be one of {SESSION_FORMATS}")
    meta = json.loads(str(data["meta"]))
    state = unflatten_state(json.loads(str(data["state"])), data)
    return meta, state


# ---- the store ----------------------------------------------------------------------------
class SessionStore:
    """Sessions by id, with a cap, idle expiry and checkpoints.

    Parameters
    ----------
    directory : Path or None
        Where checkpoints live; None keeps sessions in memory only.
    max_sessions : int
        Cap on concurrent sessions.
    idle_s : float
        A session untouched for this long is expired by :meth:`expire`.
    factory : TrackerFactory
        Builds and restores trackers (:class:`service.localizer.LocalizationFactory`).
    clock : callable
        Wall clock in seconds (injectable for tests).
    fsync : bool
        Flush each checkpoint to disk (survives power loss, not only a killed process);
        used when no ``policy`` is given.
    policy : CheckpointPolicy, optional
        When checkpoints are written (default: after every block, fsync per ``fsync``).
    """

    def __init__(
        self,
        directory: Path | None,
        max_sessions: int,
        idle_s: float,
        factory: TrackerFactory,
        clock: Callable[[], float] = time.time,
        fsync: bool = True,
        policy: CheckpointPolicy | None = None,
    ) -> None:
        self.directory = directory
        self.policy = policy or CheckpointPolicy(fsync=fsync)
        self.fsync = self.policy.fsync
        self.live = Broadcaster()  # watchers of a session (the live view)
        self.max_sessions = max_sessions
        self.idle_s = idle_s
        self.factory = factory
        self.clock = clock
        self._sessions: dict[str, Session] = {}
        self._guard = threading.Lock()  # protects the dict, never held during compute
        self._refused: dict[str, SessionRefused] = {}  # checkpoints whose map changed
        self._creating: Counter[str] = Counter()  # map id -> sessions being created on it
        if directory is not None:
            directory.mkdir(parents=True, exist_ok=True)

    # -- lookup -------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._sessions)

    def ids(self) -> list[str]:
        with self._guard:
            return sorted(self._sessions)

    def get(self, session_id: str) -> Session:
        with self._guard:
            try:
                return self._sessions[session_id]
            except KeyError:
                refused = self._refused.get(session_id)
                if refused is not None:
                    raise SessionRefused(session_id, refused.owner, str(refused)) from None
                raise SessionNotFound(session_id) from None

    def sessions_on(self, map_id: str) -> int:
        """Live sessions on ``map_id``, counting those being created right now."""
        with self._guard:
            live = sum(1 for s in self._sessions.values() if s.map_id == map_id)
            return live + self._creating[map_id]

    def expires_in_s(self, session: Session) -> float:
        return max(0.0, session.last_active_at + self.idle_s - self.clock())

    # -- lifecycle ----------------------------------------------------------------------
    def create(self, map_id: str, spec: FilterSpec, owner: str = "",
               max_per_owner: int | None = None) -> Session:
        """Build a tracker on ``map_id`` per ``spec`` and register it (checkpointed) for
        ``owner``, who may hold at most ``max_per_owner`` sessions (``SessionLimit``)."""
        self.expire()
        with self._guard:
            self._check_limits(owner, max_per_owner)
            self._creating[map_id] += 1  # counted by sessions_on while the map loads
        try:
            tracker = self.factory.create(map_id, spec)
            now = self.clock()
            session = Session(
                id=secrets.token_hex(8), map_id=map_id, spec=spec, tracker=tracker,
                created_at=now, last_active_at=now, owner=owner,
            )
            with self._guard:
                self._check_limits(owner, max_per_owner)
                self._sessions[session.id] = session
        finally:
            with self._guard:
                self._creating[map_id] -= 1
                if self._creating[map_id] <= 0:
                    del self._creating[map_id]
        with session.lock:
            self._checkpoint(session)
        return session

    def _check_limits(self, owner: str, max_per_owner: int | None) -> None:
        """Raise ``SessionLimit`` if the store or ``owner`` is full (hold ``_guard``)."""
        if len(self._sessions) >= self.max_sessions:
            raise SessionLimit(
                f"{len(self._sessions)} sessions open; max_sessions is {self.max_sessions}")
        mine = sum(1 for s in self._sessions.values() if s.owner == owner)
        if max_per_owner is not None and mine >= max_per_owner:
            raise SessionLimit(f"{mine} sessions open for this key; max_sessions_per_key "
                               f"is {max_per_owner}")

    def delete(self, session_id: str) -> None:
        with self._guard:
            if self._refused.pop(session_id, None) is not None:
                self._remove_file(session_id)
                return
        session = self.get(session_id)
        with session.lock, self._guard:
            self._sessions.pop(session_id, None)
            self._remove_file(session_id)
        self.live.close(session_id)

    def expire(self) -> list[str]:
        """Drop sessions idle for longer than ``idle_s``; returns their ids.

        The periodic sweep: it also writes the checkpoints the policy's ``every_s`` makes due.
        """
        self.flush(due_only=True)
        now = self.clock()
        with self._guard:
            stale = [s for s in self._sessions.values() if now - s.last_active_at > self.idle_s]
        gone = []
        for s in stale:
            if not s.lock.acquire(blocking=False):
                continue  # busy right now, so not idle
            try:
                with self._guard:
                    if now - s.last_active_at > self.idle_s:
                        self._sessions.pop(s.id, None)
                        self._remove_file(s.id)
                        gone.append(s.id)
            finally:
                s.lock.release()
        for session_id in gone:
            self.live.close(session_id)
        return gone

    def flush(self, due_only: bool = False) -> int:
        """Write the checkpoint of every session with unsaved blocks (only those the
        policy's ``every_s`` makes due, with ``due_only``); returns how many were written.
        Call it at shutdown: a graceful stop then loses nothing under any policy."""
        if self.directory is None:
            return 0
        with self._guard:
            dirty = [s for s in self._sessions.values() if s.pending > 0]
        written = 0
        for s in dirty:
            with s.lock:
                if self._sessions.get(s.id) is not s:
                    continue  # deleted or expired meanwhile: never write its file again
                age_s = self.clock() - s.checkpointed_at
                if s.pending > 0 and (not due_only or 0 < self.policy.every_s <= age_s):
                    self._checkpoint(s)
                    written += 1
        return written

    # -- updates ------------------------------------------------------------------------
    def update(self, session_id: str, block: BlockInput) -> tuple[int, PoseEstimate, float]:
        """Feed one block; commit (state + checkpoint) or leave the session untouched.

        Returns the committed ``(seq, estimate, processing_ms)``, read under the session's
        lock (a later request may already have moved the session on when the caller looks).

        Raises
        ------
        SessionNotFound, SessionConflict, ValueError
            Unknown id; ``seq`` not after the last committed one; a block the filter rejects.
        """
        session = self.get(session_id)
        with session.lock:
            if session.last_seq is not None and block.seq <= session.last_seq:
                raise SessionConflict(block.seq, session.last_seq)
            self._transact(session, lambda: self._apply(session, block))
            assert session.estimate is not None
            if self.live.watched(session_id):  # one dict lookup when nobody watches
                self.live.publish(session_id, session)
            return block.seq, session.estimate, session.processing_ms

    def reinit_global(self, session_id: str) -> Session:
        """Re-initialize the session's filter globally (kidnapped robot)."""
        session = self.get(session_id)
        with session.lock:
            self._transact(session, lambda: self._reinit(session), force_checkpoint=True)
            if self.live.watched(session_id):
                self.live.publish(session_id, session)
            return session

    def touch(self, session: Session) -> None:
        session.last_active_at = self.clock()

    def _apply(self, session: Session, block: BlockInput) -> None:
        t0 = time.perf_counter()
        dt = block_dt_s(block.seq, session.last_seq, session.tracker.config.block_s)
        est = session.tracker.update(replace(block, dt_s=dt))
        _check_finite(est)
        session.estimate, session.processing_ms = est, 1e3 * (time.perf_counter() - t0)
        session.last_seq = block.seq
        session.n_updates += 1

    def _reinit(self, session: Session) -> None:
        session.tracker.reinit_global()
        session.estimate = None

    def _transact(self, session: Session, change: Callable[[], None],
                  force_checkpoint: bool = False) -> None:
        """Run ``change`` then checkpoint if the policy says so (or ``force_checkpoint``);
        on any exception restore the session fully."""
        before_state = session.tracker.state_dict()
        before = (session.estimate, session.processing_ms, session.last_seq, session.n_updates,
                  session.last_active_at, session.pending, session.checkpointed_at)
        try:
            change()
            session.last_active_at = now = self.clock()
            session.pending += 1
            if force_checkpoint or self.policy.due(session.pending,
                                                   now - session.checkpointed_at):
                self._checkpoint(session)
        except BaseException:
            session.tracker.load_state_dict(before_state)
            (session.estimate, session.processing_ms, session.last_seq, session.n_updates,
             session.last_active_at, session.pending, session.checkpointed_at) = before
            raise

    # -- persistence --------------------------------------------------------------------
    def _path(self, session_id: str) -> Path | None:
        return None if self.directory is None else self.directory / f"{session_id}.npz"

    def _checkpoint(self, session: Session) -> None:
        path = self._path(session.id)
        if path is not None:
            write_checkpoint(path, session, self.policy.fsync)
        session.pending, session.checkpointed_at = 0, self.clock()

    def _remove_file(self, session_id: str) -> None:
        path = self._path(session_id)
        if path is not None and path.exists():
            os.unlink(path)

    def reload(self) -> tuple[list[str], list[str]]:
        """Restore every checkpoint in the directory; returns (loaded ids, skipped files).

        Checkpoints that cannot be read or whose map is gone are skipped (and kept on disk).
        A session whose map was overwritten since (its content hash differs: ``MapChanged``)
        is not restored either; it is *refused*: its owner gets :class:`SessionRefused`
        (409) on every request until deleting it, never a session silently on another map.
        """
        loaded: list[str] = []
        skipped: list[str] = []
        if self.directory is None:
            return loaded, skipped
        for path in sorted(self.directory.glob("*.npz")):
            try:
                meta, state = read_checkpoint(path)
                spec = FilterSpec.from_dict(meta["spec"])
                try:
                    tracker = self.factory.restore(meta["map_id"], spec, state)
                except MapChanged as exc:
                    self._refused[str(meta["id"])] = SessionRefused(
                        str(meta["id"]), str(meta.get("owner", "")), str(exc))
                    skipped.append(f"{path.name}: {exc}")
                    continue
                est = meta.get("estimate")
                session = Session(
                    id=meta["id"], map_id=meta["map_id"], spec=spec, tracker=tracker,
                    created_at=float(meta["created_at"]),
                    last_active_at=max(float(meta["last_active_at"]), self.clock()),
                    last_seq=meta["last_seq"], n_updates=int(meta["n_updates"]),
                    estimate=None if est is None else estimate_from_json(est),
                    processing_ms=0.0 if est is None else float(est.get("processing_ms", 0.0)),
                    owner=str(meta.get("owner", "")),
                )
            except (ValueError, KeyError, TypeError) as exc:
                skipped.append(f"{path.name}: {exc}")
                continue
            with self._guard:
                self._sessions[session.id] = session
            loaded.append(session.id)
        return loaded, skipped

