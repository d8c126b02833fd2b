"""Streaming writer and reader of a simulation's truth sidecar (OUT.truth.json).

Layout: one JSON object ``{"meta": {...}, "pulses": [...], "summary": {...}}`` written
incrementally, one pulse record per line, so hours of pulses never sit in memory and the
file stays valid JSON for any reader. ``summary`` (written last) holds what is only known
at the end, e.g. clipped sample counts.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any


def truth_path(wav_path: str | Path) -> Path:
    """OUT.wav -> OUT.truth.json (beside it)."""
    p = Path(wav_path)
    stem = p.name[:-4] if p.name.lower().endswith(".wav") else p.name
    return p.with_name(stem + ".truth.json")


def _clean(v: Any) -> Any:
    """JSON has no NaN/inf: write them as null."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    return v


class TruthWriter:
    """``write_pulses`` as chunks come, ``close(summary)`` at the end.

    Written to a hidden temporary file renamed to ``path`` by ``close`` (``abort`` drops
    it), so a failed simulation leaves no half sidecar.
    """

    def __init__(self, path: str | Path, meta: dict[str, Any]) -> None:
        from .files import AtomicFile

        self.path = Path(path)
        self._out = AtomicFile(self.path, "w")
        self._f = self._out.file
        self._n = 0
        try:
            self._f.write('{"meta": ' + json.dumps(_clean(meta), allow_nan=False)
                          + ',\n"pulses": [')
        except BaseException:
            self.abort()
            raise

    def write_pulses(self, records: Iterable[dict[str, Any]]) -> None:
        for r in records:
            self._f.write(("\n" if self._n == 0 else ",\n")
                          + json.dumps(_clean(r), separators=(",", ":"), allow_nan=False))
            self._n += 1

    def close(self, summary: dict[str, Any] | None = None) -> None:
        def trailer() -> None:
            self._f.write("\n],\n\"summary\": "
                          + json.dumps(_clean(summary or {}), allow_nan=False) + "}\n")
        self._out.commit(trailer)

    def abort(self) -> None:
        """Drop the temporary file; ``path`` is left as it was."""
        self._out.abort()

    @property
    def pulses_written(self) -> int:
        return self._n

    def __enter__(self) -> TruthWriter:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


#: Largest truth file read whole, bytes (an hour of pulses is about 20 MB).
MAX_TRUTH_BYTES = 64 << 20


def read_truth(path: str | Path) -> dict[str, Any]:
    """The whole truth file (for tests, plots and short runs), at most
    :data:`MAX_TRUTH_BYTES`; raises OSError, ValueError (too large, not a JSON object)."""
    from .files import NotAFile, TooLarge, read_capped

    try:
        data = read_capped(path, MAX_TRUTH_BYTES)
    except (TooLarge, NotAFile) as exc:
        raise ValueError(str(exc)) from None
    truth = json.loads(data.decode("utf-8"))
    if not isinstance(truth, dict):
        raise ValueError(f"{path}: holds a JSON {type(truth).__name__}, not a truth object")
    return truth
