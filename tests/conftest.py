"""Shared fixtures."""

from __future__ import annotations

import pytest

from furuta_rt.config import RigConfig, load_rig


@pytest.fixture
def thesis_rig() -> RigConfig:
    return load_rig("thesis")
