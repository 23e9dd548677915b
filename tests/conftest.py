"""Session-wide fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.utils.sim import small_frame_set


@pytest.fixture(scope="session")
def trex_small_set(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One small simulated frame set, shared by read-only tests (do not modify it)."""
    out = tmp_path_factory.mktemp("sets") / "trex-small"
    small_frame_set(out)
    return out
