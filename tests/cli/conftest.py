"""Small simulated lab frame sets, written once per test session and shared read-only."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from camcal.calibrate import EXPERIMENTS
from tests.utils.labsets import make_lab_set

KINDS = tuple(EXPERIMENTS)


@pytest.fixture(scope="session")
def lab_sets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, dict[str, Any]]]:
    """Per kind: the folder of a seeded lab set and its truth document. Do not modify them."""
    root = tmp_path_factory.mktemp("lab")
    return {kind: (root / kind, make_lab_set(root / kind, kind)) for kind in KINDS}
