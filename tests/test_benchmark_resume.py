"""The localization benchmark's resume check (``benchmarks.localization_echo.same_result``):
a record made on another host agrees when its floats differ in the last bits only."""

from __future__ import annotations

import math

from benchmarks.localization_echo import SAME_REL_TOL, same_result


def _record(rmse: float) -> dict[str, object]:
    return {"position_rmse_m": rmse, "lost": False, "status": {"converged": 30, "lost": 0},
            "modes": [0.25, 0.75], "first_step_ms": 12.0, "nees_mean": math.nan}


def test_last_bits_of_a_float_agree() -> None:
    # session 44: paper-a's tracked RMSE on two hosts
    a, b = 0.0015140556511220428, 0.0015140556511220355
    assert a != b
    assert same_result(_record(a), _record(b))


def test_a_real_difference_does_not_agree() -> None:
    x = 0.0015140556511220428
    assert not same_result(_record(x), _record(x * (1 + 100 * SAME_REL_TOL)))
    assert not same_result(_record(x), _record(-x))


def test_timings_are_ignored_and_structure_must_match() -> None:
    a, b = _record(0.01), _record(0.01)
    b["first_step_ms"] = 99.0
    assert same_result(a, b)
    b["modes"] = [0.25]
    assert not same_result(a, b)
    c = _record(0.01)
    c["extra"] = 1
    assert not same_result(a, c)
    d = _record(0.01)
    d["lost"] = True
    assert not same_result(a, d)
    e = _record(0.01)
    e["status"] = {"converged": 30, "lost": 1}
    assert not same_result(a, e)
