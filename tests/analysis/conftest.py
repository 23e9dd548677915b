"""Session fixtures of the transport and χ² tests: cached templates and simulated profiles.

Templates are built once per session into a temporary cache directory.
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor

import pytest

from analysis.chisq import SettingProfiles
from analysis.transport.cache import TemplateCache
from analysis.transport.templates import TemplateGrid, build_template_grid
from tests.analysis.transport_cases import CASES, grid_settings, simulate_profiles


@pytest.fixture(scope="session")
def template_cache(tmp_path_factory: pytest.TempPathFactory) -> TemplateCache:
    return TemplateCache(tmp_path_factory.mktemp("templates"))


@pytest.fixture(scope="session")
def grids(template_cache: TemplateCache) -> dict[str, TemplateGrid]:
    with ProcessPoolExecutor(2) as pool:  # the analysis takes an executor; it starts no pool of its own
        return {
            name: build_template_grid(grid_settings(c), template_cache, executor=pool)
            for name, c in CASES.items()
        }


@pytest.fixture(scope="session")
def profiles(grids: dict[str, TemplateGrid]) -> dict[str, list[SettingProfiles]]:
    return {name: simulate_profiles(c, grids[name]) for name, c in CASES.items()}
