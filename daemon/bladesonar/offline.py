"""The offline command path (pure, no I/O): ``analyze`` runs a whole recording, an array
or a stream of blocks, through the streaming analyzer (analyzer.py) and sums it up as
``bladesonar analyze`` prints it."""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np

from .analyzer import WarmStart, device_figures, new_aligner
from .config import Config
from .dsp.pulses import RecordingCheck, count_clipped, count_dropped, too_few_pulses
from .dsp.stats import median
from .errors import InputError
from .reference_build import Reference, check_compatible


def _blocks(x: np.ndarray, size: int) -> Iterator[np.ndarray]:
    for i in range(0, len(x), size):
        yield x[i:i + size]


def _regrouped(blocks: Iterable[np.ndarray], size: int) -> Iterator[np.ndarray]:
    """A stream's blocks cut again into blocks of ``size`` samples, the last shorter: the
    blocks an array is cut into (a WAV is read in blocks of 64 Ki samples, about 50
    pulses). The stages then run on the same blocks whether the recording came as an
    array or as a stream (the range scale is re-estimated at a block's start), and the
    per-block work is done a fifth as often."""
    held: list[np.ndarray] = []
    n = 0
    for b in blocks:
        b = np.asarray(b, dtype=np.float64)
        while len(b):
            take = min(size - n, len(b))
            held.append(b[:take])
            n += take
            b = b[take:]
            if n == size:
                yield held[0] if len(held) == 1 else np.concatenate(held)
                held, n = [], 0
    if held:
        yield held[0] if len(held) == 1 else np.concatenate(held)


def analyze(x: np.ndarray | Iterable[np.ndarray], cfg: Config, ref: Reference,
            track: bool = False) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Direction and rate of a recording against a reference.

    Parameters
    ----------
    x : ndarray, shape (n_samples,), or an iterable of such blocks
        Mono recording, float64; given as blocks (a WAV read in blocks) the memory used is
        independent of the recording's length (``track`` rows aside).
    cfg : Config
    ref : Reference
    track : bool
        Also return one row per pulse with the running estimate.

    Returns
    -------
    summary : dict
        direction, rotation, relative_rate, rate_hz, rpm, confidence, pulses, ...
    rows : list of dict
        Per-pulse rows (empty unless ``track``).
    """
    check_compatible(ref, cfg)
    a = cfg.analysis
    pri = cfg.waveform.pri_samples
    block = 256 * pri
    chk = RecordingCheck(pri=pri, min_pulses=a.min_pulses,
                         max_clip_fraction=a.max_clip_fraction,
                         sample_rate=cfg.audio.sample_rate)
    streamed = not isinstance(x, np.ndarray)
    warnings: list[str] = []
    if isinstance(x, np.ndarray):   # not streamed
        # a whole recording is judged before any work (block by block: no full-length
        # temporaries); a stream as it goes
        for b in _blocks(x, block):
            chk.update(b)
        warnings = chk.finish()
    # stream the recording through the same stages the daemon runs, in blocks of pulses
    # (bounded memory); the static estimate is primed from the first window of pulses
    aligner = new_aligner(cfg, ref)
    stream = WarmStart(cfg, ref, rows=track, uncertain_gaps=True)
    rows: list[dict[str, Any]] = []
    n_pulses = n_valid = 0
    edges: list[np.ndarray] = []
    status: list[np.ndarray] = []
    source = _blocks(x, block) if isinstance(x, np.ndarray) else _regrouped(x, block)
    for xb in itertools.chain(source, [None]):
        if xb is not None:
            xb = np.asarray(xb, dtype=np.float64)
            if streamed:
                chk.update(xb)
        try:
            got = aligner.flush() if xb is None else aligner.push(xb)
        except InputError:
            if streamed:
                chk.explain()              # a silent or overloaded recording's own message
            raise
        if not len(got):
            continue
        n_pulses += len(got)
        n_valid += int(got.valid.sum())
        edges.append(got.edges[got.valid])
        status.append(got.status)
        rows.extend(stream.push(got))
    if streamed:
        warnings = chk.finish()
    # a recording shorter than the static window: prime from all it holds
    rows.extend(stream.finish(a.min_pulses))
    an = stream.analyzer
    # the end of the pulse train is not a drop-out (the pulses there are not used either)
    all_status = np.concatenate(status) if status else np.zeros(0)
    dropped = count_dropped(all_status, ended=True)
    if an is None or n_valid < a.min_pulses:
        raise too_few_pulses(n_valid, n_pulses, chk.n, pri=pri,
                             sample_rate=cfg.audio.sample_rate, min_pulses=a.min_pulses,
                             dropped=dropped, clipped=count_clipped(all_status))
    # the last decision made (as the daemon's last estimate: at most decide_every - 1
    # pulses before the end)
    d = an.decided if an.decided is not None else an.decision()
    if dropped:
        warnings.append(f"{dropped} pulses dropped or corrupt (skipped)")
    if an.bursts.bursts:
        warnings.append(f"{an.bursts.bursts} pulses skipped for bursts of interference "
                        "(speech, clatter)")
    if an.aliases.last_move is not None and not any("alias" in w for w in d.warnings):
        a_, b_, k_ = an.aliases.last_move
        warnings.append(f"at pulse {k_} the track was on the alias {a_:+.3f} (relative rate) "
                        f"and was moved to {b_:+.3f}, which fits the reference table better "
                        f"({an.aliases.moves} move(s) in all; a rate near p/q blade period per "
                        "pulse shows few blade angles)")
    warnings.extend(d.warnings)
    e = np.concatenate(edges)
    # the answer for the last window (a recording's own answer, from its last window_s);
    # the events along the way come from the state machine the daemon runs
    summary = d.as_dict()
    summary["device"] = device_figures(aligner, an)
    summary.update(pulses=int(n_pulses), used_pulses=int(n_valid),
                   dropped_pulses=dropped,
                   window_s=round(min(an.window, an.seen) / cfg.prf_hz, 3),
                   outliers=int(an.tracker.outliers),
                   clock_ppm=round((float(median(np.diff(e))) / pri - 1.0) * 1e6, 1)
                   if len(e) > 2 else None,
                   events=[dict(kind=ev.kind, t_s=round(ev.t_s, 3), **ev.details())
                           for ev in an.transitions.events],
                   warnings=warnings)
    return summary, rows
