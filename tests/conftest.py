"""Shared fixtures: throwaway station files and a fast (non-realtime) mock station."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from magline.testing import deep_update

# Compiled bytecode kept, whatever the environment asks (PYTHONDONTWRITEBYTECODE, set by some CI images and
# sandboxes).  Why: the suite's workers each import magline and rewrite every test module, and its tests
# start some hundred ``magline`` processes; without the caches every one compiled the same sources again
# (collection alone 11.8 s of CPU a worker against 4.8 s).  Done here because pytest imports this file before
# it starts its workers, which inherit the environment.
sys.dont_write_bytecode = False
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "stations" / "demo.yaml"


def source_copy(dest: Path) -> Path:
    """The checkout's sources copied to ``dest``, for a test that builds a wheel.  Why: a build in the checkout
    leaves setuptools' ``build/`` there, and a module moved or deleted since stays in it and in every later
    wheel built from it."""
    import shutil

    shutil.copytree(REPO, dest, ignore=shutil.ignore_patterns(".venv", ".git", "build", "dist", "*.egg-info",
                                                              "__pycache__", "*.sqlite", "*.json", "examples"))
    return dest


def installed_plugin(site: Path, module: str, distribution: str, version: str, source: str) -> None:
    """A third-party distribution as pip leaves it in ``site`` (on ``sys.path`` by the caller): the module
    ``module`` holding ``source`` and a dist-info whose ``magline`` entry point names it."""
    package = site / module
    package.mkdir(parents=True)
    (package / "__init__.py").write_text(source, encoding="utf-8")
    info = site / f"{module}-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {distribution}\nVersion: {version}\n",
                                   encoding="utf-8")
    (info / "entry_points.txt").write_text(f"[magline]\n{module.removesuffix('_magline')} = {module}\n",
                                           encoding="utf-8")


def demo_config() -> dict:
    return yaml.safe_load(DEMO.read_text(encoding="utf-8"))


@pytest.fixture(scope="session", autouse=True)
def own_run_locks(tmp_path_factory):
    """Each test worker holds its station and vehicle locks (core/sequencer/hold.py) in a folder of its
    own: the workers run the same station files side by side, which on a real line would be refused."""
    os.environ["MAGLINE_LOCK_DIR"] = str(tmp_path_factory.mktemp("run-locks"))


@pytest.fixture
def make_station(tmp_path, monkeypatch):
    """Write a demo-derived station file into a temp dir (cwd too) and return its path."""
    monkeypatch.chdir(tmp_path)

    def make(changes: dict | None = None, name: str = "station.yaml", seed: int = 7) -> Path:
        cfg = demo_config()
        cfg = deep_update(cfg, {"products": {"MOCK-100": {"options": {"realtime": False, "seed": seed}}},
                                "acquisition": {"retry_delay_s": 0.0}})
        cfg = deep_update(cfg, changes or {})
        path = tmp_path / name
        path.write_text(yaml.safe_dump(cfg, sort_keys=False, allow_unicode=True), encoding="utf-8")
        return path

    return make


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)


@pytest.fixture(scope="session")
def postgres():
    """One throwaway PostgreSQL cluster for the whole session (see ``pg_server.py``)."""
    from pg_server import cluster

    with cluster() as server:
        yield server


@pytest.fixture(params=["sqlite", "postgresql"])
def store_url(request, tmp_path):
    """A fresh results database on each engine: the sink tests run against both."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'results.sqlite'}"
    return request.getfixturevalue("postgres").new_database()


@pytest.fixture(scope="session")
def session_chromium():
    """One headless Debian Chromium for the session (see ``browser.py``): started once, it costs seconds."""
    from browser import chromium

    with chromium() as b:
        yield b


@pytest.fixture
def browser(session_chromium):
    """The session's Chromium, with every page a test opened closed when the test ends.  A page left open
    goes on running its scripts (a screen polling a station that has stopped, a chart redrawing): left to
    the end of the session, dozens of them took the two cores from the simulated boards of later tests."""
    yield session_chromium
    for context in session_chromium.contexts:
        context.close()
