"""Shared fixtures: paths, and a fresh mosquitto broker (tests/mosquitto.py) for any test;
and how the suite is shared between two processes (pytest-xdist, ``tools/test``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mosquitto import broker  # noqa: F401  (a fixture: any test may take a fresh broker)

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"


#: Tests that wait on a real clock, process or server (the daemon paced by its audio, a
#: broker, a sound server): most of their time is waiting, and their timing is part of
#: what they check.
REALTIME_MARKS = ("realtime", "alsa", "pipewire", "broker")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under ``pytest -n 2 --dist loadgroup`` (``tools/test``): the real-time tests run one
    after another in one process, first, while the other process takes the CPU-bound
    tests; those go by module, so a module's fixtures are built once. Measured on 2 cores:
    the real-time tests took 400 s of wall time for 150 s of CPU, the others 530 s for 670 s.
    Without -n the groups mean nothing (the real-time tests just run first)."""
    if not config.pluginmanager.hasplugin("xdist"):
        return                                  # (-p no:xdist: its mark is not known)

    def realtime(item: pytest.Item) -> bool:
        return any(item.get_closest_marker(m) for m in REALTIME_MARKS)

    for item in items:
        group = "realtime" if realtime(item) else item.nodeid.split("::")[0]
        item.add_marker(pytest.mark.xdist_group(group))
    items.sort(key=lambda item: not realtime(item))       # stable: the group goes first


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return ROOT


def require_shared_sample(name: str = "fan-3d-sample") -> Path:
    """The independent 3-D recordings beside the repository (CI has them); skip without."""
    d = SHARED_DATA / name
    if not (d / "reference.wav").is_file():
        pytest.skip(f"shared sample {d} not present (clone beside the project's shared/)")
    return d
