"""Record what a ``bladesonar run`` feeds its ``LiveAnalyzer`` (for tools/feed_replay.py).

Not part of the daemon: with ``PYTHONPATH=tools/feed_dump`` and ``FEED_DUMP_DIR=DIR`` in
the environment, every Python process imports this first; a process whose command line
holds ``run`` writes ``DIR/feed-PID-TIME.npz`` at exit: each capture period it fed (wall
time, stream position, samples) and its command line (the config it read). The tests'
daemons inherit the environment, so a pytest run under these two variables dumps every
daemon of it (tests/test_daemon_pipewire.py: both paths' captures).
"""

from __future__ import annotations

import atexit
import importlib.abc
import importlib.machinery
import os
import sys
import time
from typing import Any

_DIR = os.environ.get("FEED_DUMP_DIR")
_rec: list[tuple[float, int, Any]] = []


def _install() -> None:
    import numpy as np

    from bladesonar import live

    feed = live.LiveAnalyzer.feed

    def recording_feed(self: Any, samples: Any, start_sample: int | None = None) -> None:
        _rec.append((time.time(), -1 if start_sample is None else int(start_sample),
                     np.array(samples, dtype=np.float64)))
        feed(self, samples, start_sample)

    live.LiveAnalyzer.feed = recording_feed  # type: ignore[method-assign]

    def dump() -> None:
        if "run" not in sys.argv or not _rec or _DIR is None:
            return
        os.makedirs(_DIR, exist_ok=True)
        np.savez(os.path.join(_DIR, f"feed-{os.getpid()}-{int(time.time())}.npz"),
                 t=np.array([r[0] for r in _rec]), start=np.array([r[1] for r in _rec]),
                 lens=np.array([len(r[2]) for r in _rec]),
                 x=np.concatenate([r[2] for r in _rec]), argv=np.array(sys.argv))

    atexit.register(dump)


class _Finder(importlib.abc.MetaPathFinder):
    """Wraps ``bladesonar.live`` once it is imported (importing it here would slow every
    process and change nothing the daemon does)."""

    def find_spec(self, name: str, path: Any, target: Any = None) -> Any:
        if name != "bladesonar.live":
            return None
        sys.meta_path.remove(self)
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.loader is None:
            return spec
        run = spec.loader.exec_module

        def exec_module(module: Any) -> None:
            run(module)
            sys.modules[name] = module
            _install()

        spec.loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec


if _DIR:
    sys.meta_path.insert(0, _Finder())
