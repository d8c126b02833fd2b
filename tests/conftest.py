"""Shared fixtures: paths, and a fresh mosquitto broker (tests/mosquitto.py) for any test."""

from __future__ import annotations

from pathlib import Path

import pytest

from mosquitto import broker  # noqa: F401  (a fixture: any test may take a fresh broker)

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return ROOT


def require_shared_sample(name: str = "fan-3d-sample") -> Path:
    """The independent 3-D recordings beside the repository (CI has them); skip without."""
    d = SHARED_DATA / name
    if not (d / "reference.wav").is_file():
        pytest.skip(f"shared sample {d} not present (clone beside the project's shared/)")
    return d
