"""Session store: commit/restore semantics, checkpoints, reload, cap and idle expiry."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.signal import SonarConfig
from service.engine import BlockInput, EstimateOut, FilterSpec, wrap_angle
from service.sessions import (
    SessionConflict,
    SessionLimit,
    SessionNotFound,
    SessionStore,
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
    return BlockInput(seq=seq, samples=x, fs_hz=CFG.fs_hz, speed_m_s=speed,
                      yaw_rate_rad_s=yaw_rate)


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
    assert s.last_seq == 0 and s.n_updates == 1 and s.estimate == est_before
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
    assert s2.estimate == s.estimate
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


@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_wrap_angle_range(a: float) -> None:
    w = wrap_angle(a)
    assert -math.pi < w <= math.pi
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-6)
    assert math.isclose(math.sin(w), math.sin(a), abs_tol=1e-6)


def test_wrap_angle_edges() -> None:
    assert wrap_angle(-math.pi) == math.pi and wrap_angle(math.pi) == math.pi
    assert wrap_angle(3 * math.pi) == pytest.approx(math.pi)


def test_covariance_ros_layout() -> None:
    cov = ((1.0, 0.1, 0.2), (0.1, 2.0, 0.3), (0.2, 0.3, 3.0))
    est = EstimateOut(pose=(0, 0, 0), covariance=cov, modes=(), ess=1.0, converged=False,
                      direction_observable=False)
    c6 = np.asarray(est.covariance_ros()).reshape(6, 6)
    assert c6[0, 0] == 1.0 and c6[1, 1] == 2.0 and c6[5, 5] == 3.0
    assert c6[0, 5] == 0.2 and c6[5, 1] == 0.3 and c6[0, 1] == 0.1
    assert np.all(c6[2:5, :] == 0) and np.all(c6[:, 2:5] == 0)
    assert EstimateOut.from_dict(est.to_dict()) == est


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
