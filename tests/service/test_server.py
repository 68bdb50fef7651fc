"""``service.server``: the malloc-arena cap ``omnisonar serve`` applies (the RSS growth of
the load benchmark) and its setting."""

from __future__ import annotations

import subprocess
import sys

import pytest
from pydantic import ValidationError

from service.settings import Settings


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_arena_cap_is_applied_by_glibc_and_zero_leaves_it() -> None:
    """In a fresh interpreter (not to change this one's allocator): mallopt(M_ARENA_MAX)
    accepts 2; 0 means no change and reports so."""
    code = ("from service.server import limit_malloc_arenas as f; "
            "print(f(2), f(0), f(-1))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["True", "False", "False"]


def test_arena_setting_is_bounded(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OMNISONAR_MALLOC_ARENAS", "4")
    assert Settings().malloc_arenas == 4
    assert Settings(malloc_arenas=0).malloc_arenas == 0
    with pytest.raises(ValidationError, match="malloc_arenas"):
        Settings(malloc_arenas=-1)
