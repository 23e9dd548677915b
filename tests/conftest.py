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


@pytest.fixture(scope="session")
def dive_data(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, object]]:
    """A data folder filled by a real simulated dive (~30 s), shared by read-only tests.

    Tests that write to a store copy it first (`tests.utils.dive_store.copy_data`).
    """
    from tests.utils.dive_store import run_simulated_dive  # the live stack, imported only when needed

    root = tmp_path_factory.mktemp("dive")
    info = run_simulated_dive(root / "data")
    return root / "data", info
