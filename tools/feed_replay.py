"""Replay what daemons were fed (tools/feed_dump) through ``LiveAnalyzer`` offline, as the
daemon reads it (``wanted()`` periods at a time), and say where the paths part.

  PYTHONPATH=tools/feed_dump FEED_DUMP_DIR=/tmp/feeds \\
      .venv/bin/python -m pytest tests/test_daemon_pipewire.py -k 44k1 -s --basetemp=/tmp/pw
  .venv/bin/python tools/feed_replay.py /tmp/feeds/feed-A.npz /tmp/feeds/feed-B.npz

Each dump is replayed with the config its command line named and the reference in that
config's state_dir (keep the test's temporary folders: --basetemp). Printed per dump: the
reference (pulses, sha256), the first decisions' pulse numbers, the events (pulse, the
capture period after which the daemon gave them out, and how long after the dump's
start it had fed that period); for two dumps, whether their aligned pulses agree, the
first decision where they differ, and the events with the references swapped (which of
the reference or the capture moves the answer). How issue 35's 44.1 kHz comparison was
traced to two references (docs/audio.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from bladesonar.analyzer import new_aligner
from bladesonar.io.config_file import load_config
from bladesonar.io.reference import load_reference
from bladesonar.live import LiveAnalyzer
from bladesonar.transitions import Transitions


def load(path: str) -> dict[str, Any]:
    """A dump with its config and reference: the ones its command line named, or, when
    the test's folder is gone, cfg.yaml and state/reference.npz beside the dump."""
    z = np.load(path)
    argv = [str(a) for a in z["argv"]]
    here = Path(path).parent
    named = Path(argv[argv.index("--config") + 1])
    cfg = load_config(named if named.is_file() else here / "cfg.yaml")
    ref = Path(cfg.reference_path)
    if not ref.is_file():
        ref = here / "state" / "reference.npz"
    return {"z": z, "cfg": cfg, "ref": load_reference(ref), "path": path}


def replay(d: dict[str, Any], ref: Any = None, block_pulses: int = 8) -> dict[str, Any]:
    """The dump through the daemon's path: decisions (pulse, direction, confidence) and
    events (kind, pulse, last capture period read, wall time it was fed)."""
    z, cfg = d["z"], d["cfg"]
    la = LiveAnalyzer(cfg, d["ref"] if ref is None else ref, block_pulses=block_pulses)
    decided: list[tuple[int, str, float]] = []
    events: list[tuple[str, int, int, float]] = []
    step = Transitions.step

    def watch(self: Transitions, t_s: float, k: int, dd: Any, since: int) -> Any:
        st, fired = step(self, t_s, k, dd, since)
        decided.append((k, st.direction.value, round(st.confidence, 4)))
        return st, fired

    ends = np.cumsum(z["lens"])
    i, n = 0, len(z["lens"])
    Transitions.step = watch  # type: ignore[method-assign,assignment]
    try:
        while i < n:
            for _ in range(la.wanted()):
                if i >= n:
                    break
                la.feed(z["x"][ends[i] - z["lens"][i]:ends[i]], int(z["start"][i]))
                i += 1
            events += [(e.kind.value, e.pulse, i - 1, float(z["t"][i - 1] - z["t"][0]))
                       for e in la.take_events()]
    finally:
        Transitions.step = step  # type: ignore[method-assign]
    return {"decided": decided, "events": events}


def aligned(d: dict[str, Any]) -> Any:
    return new_aligner(d["cfg"], d["ref"]).push(d["z"]["x"])


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("dumps", nargs="+", help="feed-*.npz from tools/feed_dump")
    p.add_argument("--block-pulses", type=int, default=8)
    args = p.parse_args(argv)
    ds = [load(f) for f in args.dumps]
    runs = [replay(d, block_pulses=args.block_pulses) for d in ds]
    for d, r in zip(ds, runs, strict=True):
        m = d["ref"].meta
        print(f"{d['path']}: reference {m.get('pulses')} pulses, sha256 "
              f"{str(m.get('sha256'))[:12]}; first decisions "
              f"{[k for k, _, _ in r['decided'][:4]]}; events {r['events']}")
    if len(ds) == 2:
        a, b = aligned(ds[0]), aligned(ds[1])
        m = min(len(a), len(b))
        same = np.max(np.abs(a.pulses[:m] - b.pulses[:m])) if m else float("nan")
        print(f"aligned pulses: {len(a)} and {len(b)}, numbers alike "
              f"{bool(np.array_equal(a.index[:m], b.index[:m]))}, largest difference "
              f"{same:.3g}, first edges {a.edges[0]:.2f} and {b.edges[0]:.2f}")
        da, db = dict((k, rest) for k, *rest in runs[0]["decided"]), \
            dict((k, rest) for k, *rest in runs[1]["decided"])
        diff = [k for k in sorted(set(da) & set(db)) if da[k] != db[k]]
        print("first differing decision:",
              f"pulse {diff[0]}: {da[diff[0]]} against {db[diff[0]]}" if diff else "none")
        for x, y in ((0, 1), (1, 0)):
            swapped = replay(ds[x], ref=ds[y]["ref"], block_pulses=args.block_pulses)
            print(f"dump {x + 1} with reference {y + 1}: events "
                  f"{[e[:2] for e in swapped['events']]}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
