"""Tests of FilterConfig: validation names the field, JSON round trip."""

from __future__ import annotations

import pytest

from localization.particle_filter import (
    FilterConfig,
)


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="n_particles"):
        FilterConfig(n_particles=0)
    with pytest.raises(ValueError, match="alpha_slow"):
        FilterConfig(alpha_slow=0.5, alpha_fast=0.1)
    assert FilterConfig.from_json(FilterConfig(n_particles=7).to_json()).n_particles == 7
