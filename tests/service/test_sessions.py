"""Session store: commit/restore semantics, checkpoints, reload, cap and idle expiry."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.files import atomic_savez
from mapping.signal import SonarConfig
from service.sessions import (
    BlockInput,
    FilterSpec,
    InvalidSpec,
    SessionConflict,
    SessionLimit,
    SessionNotFound,
    SessionStore,
    estimate_from_json,
    estimate_to_json,
    flatten_state,
    read_checkpoint,
    unflatten_state,
)
from tests.service.doubles import OdometryFactory

CFG = SonarConfig()


def _block(seq: int, speed: float = 0.2, yaw_rate: float = 0.0, bad: bool = False) -> BlockInput:
    x = np.zeros(CFG.block_samples)
    if bad:
        x[0] = 1e6
    return BlockInput(seq=seq, samples=x, speed_m_s=speed, yaw_rate_rad_s=yaw_rate)


def _store(tmp_path: Path, **kw: object) -> tuple[SessionStore, OdometryFactory]:
    fac = OdometryFactory()
    clock = kw.pop("clock", None)
    store = SessionStore(tmp_path / "sessions", int(kw.pop("max_sessions", 4)),  # type: ignore[call-overload]
                         float(kw.pop("idle_s", 60.0)), fac,  # type: ignore[arg-type]
                         **({"clock": clock} if clock else {}))  # type: ignore[arg-type]
    return store, fac


SPEC = FilterSpec(kind="pf", particles=50, seed=3, initial_pose=(1.0, 2.0, 0.0))


def test_update_commits_and_checkpoints(tmp_path: Path) -> None:
    store, _ = _store(tmp_path)
    s = store.create("m", SPEC)
    store.update(s.id, _block(0, speed=0.2))
    store.update(s.id, _block(1, speed=0.2))
    assert s.last_seq == 1 and s.n_updates == 2
    assert s.estimate is not None
    # dead reckoning of the double: the first block has dt 0, the second one block_s
    assert s.estimate.pose[0] == pytest.approx(1.0 + 0.2 * CFG.block_s, abs=0.01)
    store.update(s.id, _block(4, speed=0.2))  # blocks 2, 3 lost: a step of 3 blocks
    assert s.estimate.pose[0] == pytest.approx(1.0 + 4 * 0.2 * CFG.block_s, abs=0.01)
    meta, state = read_checkpoint(tmp_path / "sessions" / f"{s.id}.npz")
    assert meta["last_seq"] == 4
    np.testing.assert_array_equal(state["poses"], s.tracker.state_dict()["poses"])


def test_duplicate_and_old_seq_leave_everything_untouched(tmp_path: Path) -> None:
    store, _ = _store(tmp_path)
    s = store.create("m", SPEC)
    store.update(s.id, _block(5))
    path = tmp_path / "sessions" / f"{s.id}.npz"
    before_file = path.read_bytes()
    before_state = s.tracker.state_dict()
    for seq in (5, 4, 0):
        with pytest.raises(SessionConflict):
            store.update(s.id, _block(seq))
    assert path.read_bytes() == before_file
    after = s.tracker.state_dict()
    np.testing.assert_array_equal(after["poses"], before_state["poses"])
    assert after["rng"] == before_state["rng"] and s.last_seq == 5


def test_failure_after_mutation_is_rolled_back(tmp_path: Path) -> None:
    store, fac = _store(tmp_path)
    s = store.create("m", SPEC)
    store.update(s.id, _block(0))
    path = tmp_path / "sessions" / f"{s.id}.npz"
    before_file, before = path.read_bytes(), s.tracker.state_dict()
    est_before = s.estimate
    with pytest.raises(ValueError):
        store.update(s.id, _block(1, bad=True))  # the double mutates, then raises
    assert path.read_bytes() == before_file
    np.testing.assert_array_equal(s.tracker.state_dict()["poses"], before["poses"])
    assert s.tracker.state_dict()["rng"] == before["rng"]
    assert s.last_seq == 0 and s.n_updates == 1 and s.estimate is est_before
    store.update(s.id, _block(1))  # the same seq is still free
    assert s.last_seq == 1


def test_reload_restores_sessions_exactly(tmp_path: Path) -> None:
    store, _ = _store(tmp_path)
    s = store.create("m", SPEC)
    for k in range(3):
        store.update(s.id, _block(k, speed=0.1, yaw_rate=0.2))
    store2, _ = _store(tmp_path)
    loaded, skipped = store2.reload()
    assert loaded == [s.id] and skipped == []
    s2 = store2.get(s.id)
    assert (s2.last_seq, s2.n_updates, s2.spec) == (2, 3, SPEC)
    assert s.estimate is not None and s2.estimate is not None
    assert estimate_to_json(s2.estimate) == estimate_to_json(s.estimate)
    assert s2.processing_ms == s.processing_ms
    # both continue identically (the rng state travelled with the checkpoint)
    store.update(s.id, _block(3, speed=0.1, yaw_rate=0.2))
    store2.update(s.id, _block(3, speed=0.1, yaw_rate=0.2))
    np.testing.assert_array_equal(s.tracker.state_dict()["poses"],
                                  s2.tracker.state_dict()["poses"])


def test_reload_skips_corrupt_checkpoint(tmp_path: Path) -> None:
    store, _ = _store(tmp_path)
    s = store.create("m", SPEC)
    (tmp_path / "sessions" / "junk.npz").write_bytes(b"not a zip")
    store2, _ = _store(tmp_path)
    loaded, skipped = store2.reload()
    assert loaded == [s.id] and len(skipped) == 1 and "junk.npz" in skipped[0]


def test_cap_and_delete(tmp_path: Path) -> None:
    store, _ = _store(tmp_path, max_sessions=2)
    a = store.create("m", SPEC)
    store.create("m", SPEC)
    with pytest.raises(SessionLimit):
        store.create("m", SPEC)
    store.delete(a.id)
    assert not (tmp_path / "sessions" / f"{a.id}.npz").exists()
    with pytest.raises(SessionNotFound):
        store.get(a.id)
    store.create("m", SPEC)
    assert len(store) == 2


def test_idle_expiry(tmp_path: Path) -> None:
    now = [1000.0]
    store, _ = _store(tmp_path, idle_s=10.0, clock=lambda: now[0])
    a = store.create("m", SPEC)
    b = store.create("m", SPEC)
    now[0] += 6
    store.update(b.id, _block(0))
    now[0] += 6  # a idle 12 s, b idle 6 s
    assert store.expire() == [a.id]
    assert store.ids() == [b.id]
    assert not (tmp_path / "sessions" / f"{a.id}.npz").exists()


def test_reinit_global_keeps_seq(tmp_path: Path) -> None:
    store, _ = _store(tmp_path)
    s = store.create("m", SPEC)
    store.update(s.id, _block(7))
    store.reinit_global(s.id)
    assert s.last_seq == 7 and s.estimate is None
    with pytest.raises(SessionConflict):
        store.update(s.id, _block(7))


state_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.text(max_size=5)
    | st.floats(allow_nan=False) | st.builds(lambda n: np.arange(n, dtype=np.float64),
                                             st.integers(0, 4)),
    lambda kids: st.lists(kids, max_size=3)
    | st.dictionaries(st.text("abc", min_size=1, max_size=3), kids, max_size=3),
    max_leaves=8,
)


@settings(max_examples=60, deadline=None)
@given(st.dictionaries(st.text("xyz_", min_size=1, max_size=4), state_values, max_size=4))
def test_flatten_roundtrip(state: dict[str, object]) -> None:
    arrays, tree = flatten_state(state)
    back = unflatten_state(tree, arrays)

    def same(a: object, b: object) -> bool:
        if isinstance(a, np.ndarray):
            return isinstance(b, np.ndarray) and np.array_equal(a, b)
        if isinstance(a, dict):
            return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k])
                                                                        for k in a)
        if isinstance(a, list | tuple):
            return isinstance(b, list) and len(a) == len(b) and all(map(same, a, b))
        return a == b

    assert same(state, back)


def test_estimate_json_roundtrip_is_exact(tmp_path: Path) -> None:
    store, _ = _store(tmp_path)
    s = store.create("m", SPEC)
    store.update(s.id, _block(0, speed=0.3, yaw_rate=0.1))
    assert s.estimate is not None
    d = estimate_to_json(s.estimate)
    back = estimate_from_json(json.loads(json.dumps(d)))
    assert estimate_to_json(back) == d
    np.testing.assert_array_equal(back.modes[0].cov, s.estimate.modes[0].cov)
    flagged = dataclasses.replace(s.estimate, reckoned=True, refined=False)
    assert estimate_from_json(json.loads(json.dumps(estimate_to_json(flagged)))).reckoned
    old = {k: v for k, v in d.items() if k not in ("reckoned", "reason")}  # written before
    assert estimate_from_json(old).reckoned is False and estimate_from_json(old).reason == ""
    doubt = dataclasses.replace(s.estimate, status="uncertain", reason="rival_doubt")
    assert estimate_from_json(json.loads(json.dumps(estimate_to_json(doubt)))).reason == (
        "rival_doubt")


def test_format_1_checkpoint_still_loads(tmp_path: Path) -> None:
    """A checkpoint written before the store kept the core's estimate (format 1: the
    service's flat estimate) loads with the estimate it reported and continues."""
    store, _ = _store(tmp_path)
    s = store.create("m", SPEC)
    store.update(s.id, _block(0))
    state = s.tracker.state_dict()
    old_est = {"pose": [1.0, 2.0, 3.0], "covariance": np.diag([1.0, 2.0, 3.0]).tolist(),
               "modes": [[1.0, 2.0, 3.0, 0.75], [0.0, 0.0, -1.0, 0.25]], "ess": 40.0,
               "converged": True, "direction_observable": False,
               "covariance_all": np.diag([4.0, 5.0, 6.0]).tolist(), "processing_ms": 12.5,
               "extra": {"model": "range", "updated": True, "likelihood_scale": 0.5}}
    meta = {**s.meta(), "estimate": old_est}
    arrays, tree = flatten_state(state)
    atomic_savez(tmp_path / "sessions" / f"{s.id}.npz",
                 {"format": np.array("omnisonar-session-1"), "meta": np.array(json.dumps(meta)),
                  "state": np.array(json.dumps(tree)), **arrays})
    store2, _ = _store(tmp_path)
    assert store2.reload() == ([s.id], [])
    est = store2.get(s.id).estimate
    assert est is not None and store2.get(s.id).processing_ms == 12.5
    assert est.pose.tolist() == [1.0, 2.0, 3.0] and est.cov[2, 2] == 3.0
    assert est.cov_all[0, 0] == 4.0 and est.likelihood_scale == 0.5 and est.model == "range"
    assert [(m.weight, m.mean.tolist()) for m in est.modes] == [(0.75, [1.0, 2.0, 3.0]),
                                                                 (0.25, [0.0, 0.0, -1.0])]
    np.testing.assert_array_equal(store2.get(s.id).tracker.state_dict()["poses"],
                                  state["poses"])
    store2.update(s.id, _block(1))
    assert store2.get(s.id).last_seq == 1


def test_non_finite_estimate_is_not_committed(tmp_path: Path) -> None:
    store, fac = _store(tmp_path)
    s = store.create("m", SPEC)
    store.update(s.id, _block(0))
    path = tmp_path / "sessions" / f"{s.id}.npz"
    before_file, est = path.read_bytes(), s.estimate
    fac.created[-1].poses[0, 0] = math.nan  # a numerical failure inside the filter
    with pytest.raises(FloatingPointError):
        store.update(s.id, _block(1))
    assert path.read_bytes() == before_file
    assert s.last_seq == 0 and s.n_updates == 1 and s.estimate is est


def test_factory_refusal_names_the_field() -> None:
    store = SessionStore(None, 4, 60.0, OdometryFactory({"m"}))
    with pytest.raises(InvalidSpec) as err:
        store.create("other", SPEC)
    assert err.value.field == "map_id" and len(store) == 0


def test_same_seq_from_many_threads_commits_once(tmp_path: Path) -> None:
    import threading

    store, _ = _store(tmp_path)
    s = store.create("m", SPEC)
    results: list[str] = []

    def send() -> None:
        try:
            store.update(s.id, _block(1))
            results.append("ok")
        except SessionConflict:
            results.append("409")

    threads = [threading.Thread(target=send) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(results) == ["409"] * 7 + ["ok"]
    assert s.n_updates == 1 and s.last_seq == 1


def test_checkpoint_without_fsync_is_the_same_file(tmp_path: Path) -> None:
    store, _ = _store(tmp_path)
    s = store.create("m", SPEC)
    store.update(s.id, _block(0))
    from service.sessions import write_checkpoint

    write_checkpoint(tmp_path / "a.npz", s, fsync=True)
    write_checkpoint(tmp_path / "b.npz", s, fsync=False)
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


# ---- checkpoint policy (issue 17 item 6) --------------------------------------------------
def _policy_store(tmp_path: Path, policy: object, now: list[float]) -> SessionStore:
    from service.sessions import CheckpointPolicy

    assert isinstance(policy, CheckpointPolicy)
    return SessionStore(tmp_path / "sessions", 4, 1e9, OdometryFactory(),  # type: ignore[arg-type]
                        clock=lambda: now[0], policy=policy)


def _on_disk(tmp_path: Path, sid: str) -> int:
    meta, _ = read_checkpoint(tmp_path / "sessions" / f"{sid}.npz")
    return int(meta["n_updates"])


def test_policy_every_n_blocks_and_flush(tmp_path: Path) -> None:
    from service.sessions import CheckpointPolicy

    now = [0.0]
    store = _policy_store(tmp_path, CheckpointPolicy(every_blocks=3), now)
    s = store.create("m", SPEC)
    for k in range(4):
        store.update(s.id, _block(k))
        assert _on_disk(tmp_path, s.id) == (3 if k >= 2 else 0)
    assert s.pending == 1
    assert store.flush() == 1 and _on_disk(tmp_path, s.id) == 4  # a graceful stop
    assert store.flush() == 0
    # a restart (the crash case) resumes from the last checkpoint written
    again = _policy_store(tmp_path, CheckpointPolicy(every_blocks=3), now)
    assert again.reload()[0] == [s.id] and again.get(s.id).last_seq == 3


def test_policy_every_t_seconds_at_blocks_and_at_the_sweep(tmp_path: Path) -> None:
    from service.sessions import CheckpointPolicy

    now = [0.0]
    store = _policy_store(tmp_path, CheckpointPolicy(every_blocks=0, every_s=10.0), now)
    s = store.create("m", SPEC)
    for k in range(3):
        now[0] = 1.0 + k
        store.update(s.id, _block(k))
    assert _on_disk(tmp_path, s.id) == 0
    now[0] = 10.5
    store.update(s.id, _block(3))  # the checkpoint is 10.5 s old: written with this block
    assert _on_disk(tmp_path, s.id) == 4
    store.update(s.id, _block(4))
    store.expire()  # the periodic sweep: not due yet
    assert _on_disk(tmp_path, s.id) == 4
    now[0] = 21.0
    store.expire()  # due: written without a block
    assert _on_disk(tmp_path, s.id) == 5 and s.pending == 0


def test_policy_flush_never_rewrites_a_deleted_session(tmp_path: Path) -> None:
    from service.sessions import CheckpointPolicy

    store = _policy_store(tmp_path, CheckpointPolicy(every_blocks=5), [0.0])
    s = store.create("m", SPEC)
    store.update(s.id, _block(0))
    store.delete(s.id)
    assert store.flush() == 0 and not (tmp_path / "sessions" / f"{s.id}.npz").exists()


def test_policy_rejects_negative_values() -> None:
    from service.sessions import CheckpointPolicy

    with pytest.raises(ValueError, match="every_blocks"):
        CheckpointPolicy(every_blocks=-1)
    with pytest.raises(ValueError):
        CheckpointPolicy(every_s=float("nan"))
    assert CheckpointPolicy().due(1, 0.0)  # the default: after every block
    assert not CheckpointPolicy(every_blocks=0).due(100, 1e9)  # shutdown-only


def test_failed_checkpoint_under_a_policy_restores_the_pending_count(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import service.sessions as sessions_module
    from service.sessions import CheckpointPolicy

    store = _policy_store(tmp_path, CheckpointPolicy(every_blocks=2), [0.0])
    s = store.create("m", SPEC)
    store.update(s.id, _block(0))

    def fail(*_: object, **__: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(sessions_module, "write_checkpoint", fail)
    with pytest.raises(OSError):
        store.update(s.id, _block(1))  # the checkpoint was due and failed: not committed
    assert (s.last_seq, s.n_updates, s.pending) == (0, 1, 1)


def test_app_checkpoint_policy_from_settings_and_flush_at_shutdown(tmp_path: Path) -> None:
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.settings import Settings

    cfg = Settings(maps_dir=tmp_path / "maps", sessions_dir=tmp_path / "sessions",
                   default_map=False, checkpoint_every_blocks=10, checkpoint_every_s=30.0)
    app = create_app(cfg, factory=lambda _: OdometryFactory())  # type: ignore[arg-type, return-value]
    with TestClient(app) as client:
        store: SessionStore = app.state.sessions
        assert (store.policy.every_blocks, store.policy.every_s) == (10, 30.0)
        s = store.create("m", SPEC)
        store.update(s.id, _block(0))
        assert _on_disk(tmp_path, s.id) == 0
        assert client.get("/health").status_code == 200
    assert _on_disk(tmp_path, s.id) == 1  # the lifespan's end wrote the pending block


def test_sessions_on_counts_live_and_in_flight_sessions(tmp_path: Path) -> None:
    """``DELETE /maps/{id}`` asks this: a session whose map is still loading counts too."""
    import threading

    store, fac = _store(tmp_path)
    loading, release = threading.Event(), threading.Event()
    create = fac.create

    def slow_create(map_id: str, spec: FilterSpec) -> object:
        loading.set()
        release.wait(10)
        return create(map_id, spec)

    fac.create = slow_create  # type: ignore[method-assign, assignment]
    t = threading.Thread(target=store.create, args=("m", SPEC))
    t.start()
    try:
        assert loading.wait(10)
        assert store.sessions_on("m") == 1 and store.sessions_on("other") == 0
    finally:
        release.set()
        t.join(10)
    assert store.sessions_on("m") == 1  # now live
    store.delete(store.ids()[0])
    assert store.sessions_on("m") == 0
    fac.map_ids = set()  # a refused creation leaves no count behind
    with pytest.raises(InvalidSpec):
        store.create("m", SPEC)
    assert store.sessions_on("m") == 0
