"""Fixtures shared by the localization tests.

``tables``: the sensor lookup tables of the asymmetric test room (tests/localization/helpers.py),
built once per session; the filters never modify them.
"""

from __future__ import annotations

import pytest

from localization.sensor import SensorTables
from tests.localization.helpers import asymmetric_tables


@pytest.fixture(scope="session")
def tables() -> SensorTables:
    return asymmetric_tables()
