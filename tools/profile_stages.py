"""CPU per pulse of each analysis stage, from a cProfile run (shared by tools/bench_analyze
and tools/bench_daemon --profile, so both split the time the same way)."""

from __future__ import annotations

import pstats
import sys

#: (stage, functions whose cumulative time it is): the analysis stages in pipeline order
STAGES = (
    ("align", ("pulses.py", "push"), ("pulses.py", "flush")),
    ("clutter", ("analyzer.py", "__call__"),),
    ("features", ("fingerprint.py", "envelope_features"),),
    ("match", ("fingerprint.py", "match"), ("aliasing.py", "distances")),
    ("track", ("tracking.py", "update"),),
    ("alias_check", ("analyzer.py", "_check_aliases"), ("analyzer.py", "_recheck_track")),
    ("decide", ("analyzer.py", "decision"),),
    ("transitions", ("transitions.py", "step"),),
)


def stage_split(st: pstats.Stats, pulses: int) -> dict[str, float]:
    """ms per pulse of each of STAGES (cumulative times of its functions) and ``total``
    (every function's own time: all that the profiled thread spent)."""
    stats = st.stats  # type: ignore[attr-defined]  # pstats keeps them there
    out = {}
    for name, *funcs in STAGES:
        t = sum(v[3] for (f, _, fn), v in stats.items()
                if any(f.endswith(a) and fn == b for a, b in funcs))
        out[name] = round(1e3 * t / max(pulses, 1), 4)
    out["total"] = round(1e3 * sum(v[2] for v in stats.values()) / max(pulses, 1), 4)
    return out


def print_top(st: pstats.Stats, n: int = 25) -> None:
    """The ``n`` functions with the most own time, to stderr."""
    st.stream = sys.stderr  # type: ignore[attr-defined]
    st.sort_stats("tottime").print_stats(n)
