"""Shared fixtures: one site cache for the whole session (small sites are built once)."""

import pytest


@pytest.fixture(scope="session")
def session_cache(tmp_path_factory):
    """A LUNAR_DRAKE_CACHE directory shared by every test of the session."""
    return tmp_path_factory.mktemp("lunar_drake_cache")


@pytest.fixture
def cache(session_cache, monkeypatch):
    """Points LUNAR_DRAKE_CACHE at the session's cache (sites and kernels built once)."""
    monkeypatch.setenv("LUNAR_DRAKE_CACHE", str(session_cache))
    return session_cache


@pytest.fixture
def small_site(cache):
    """The ``small`` scenario and its loaded site."""
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.site import load_site

    scenario = load_scenario(scenario_name="small")
    return scenario, load_site(scenario, progress=False)
