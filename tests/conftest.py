"""Shared test helpers: fixtures and real corpus files, loaded by name.

Corpus files live in ``../shared/corpus/`` beside the project and are never copied into the repo;
tests that need them skip cleanly when the folder is missing.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import settings

# `make test` draws the same property-test examples on every run, so a CI run fails on a change to
# the code and not on an unlucky new draw; `make test-explore` draws fresh ones (run it after
# touching the geometry core, and turn what it finds into a fixed test).
settings.register_profile("repeatable", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile("repeatable")

ROOT = Path(__file__).resolve().parent.parent
FIXTURES = ROOT / "fixtures"
CORPUS = ROOT.parent / "shared" / "corpus"


@pytest.fixture(autouse=True)
def _private_duration_cache(tmp_path_factory, monkeypatch):
    """Batch runs keep per-file times in a user cache; tests keep theirs in a temporary folder."""
    monkeypatch.setenv("WATERTIGHT_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))


def fixture_path(name: str) -> Path:
    path = FIXTURES / name
    if not path.exists():
        pytest.fail(f"fixture {name} is missing: run `make fixtures`")
    return path


def corpus_path(name: str) -> Path:
    path = CORPUS / name
    if not path.exists():
        pytest.skip(f"corpus file {name} not available (../shared/corpus missing)")
    return path


def corpus_files() -> list[str]:
    if not CORPUS.is_dir():
        return []
    return sorted(p.name for p in CORPUS.iterdir() if p.suffix.lower() in (".step", ".stp", ".igs", ".iges"))


def fixture_models() -> list[str]:
    return sorted(p.name for p in FIXTURES.iterdir()
                  if p.is_file() and p.suffix.lower() in (".step", ".stp", ".igs", ".iges"))


def corpus_table() -> dict[str, dict]:
    """The corpus README's table (figures measured by the independent checker), by file name."""
    readme = CORPUS / "README.md"
    if not readme.exists():
        return {}
    rows = {}
    for line in readme.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 7 and cells[0].startswith("`"):
            name = cells[0].strip("`")
            try:
                rows[name] = {"faces": int(cells[2]), "max_gap": float(cells[4]), "free": int(cells[5]),
                              "diag": float(cells[6])}
            except ValueError:
                continue
    return rows


@pytest.fixture(scope="session")
def tol():
    from watertight_cli.tolerances import Tolerances

    return Tolerances(strict=True)
