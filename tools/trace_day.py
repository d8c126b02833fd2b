"""Trace a moment of a `tools/bench_day` day: save the live pipeline shortly before it,
then replay the pulses from there with the tracker's and state machine's internals printed.
A developer's tool: the day takes minutes per simulated hour to reach a late moment, a
replay a second or two.

  .venv/bin/python tools/trace_day.py save --hours 4 --seed 14 --at 13392 13505 --out DIR
  .venv/bin/python tools/trace_day.py save --random-scene --hours 0.4 --seed 7 --at 800 --out DIR
  .venv/bin/python tools/trace_day.py replay DIR/seed14_13505.pkl [--from T] [--to T]

Times are the day's stream times (s), as bench_day's false/missed details give them. The
day is bench_day's own (tools/days.py); a change of the code under test after a save is
replayed from the saved state, so save again after changing what runs before the moment.
"""

from __future__ import annotations

import argparse
import math
import pickle
import sys
from pathlib import Path
from typing import Any

import numpy as np
from days import DRIFT_PPM, day, random_day  # tools/days.py

from bladesonar.live import LiveAnalyzer
from bladesonar.sim.schedule import Schedule
from bladesonar.sim.score import true_time


def save(args: argparse.Namespace) -> None:
    if args.random_scene:
        cfg, sch, sim, live, dr = random_day(args.hours, args.seed)
        drift = dr.drift_ppm
    else:
        cfg, sch, sim, live, _ = day(args.hours, args.seed)
        drift = DRIFT_PPM
    pri, fs = cfg.waveform.pri_samples, cfg.audio.sample_rate
    marks = sorted(args.at)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    pending: list[dict[str, Any]] = []      # saved, still gathering their audio
    pos, buf = 0, np.zeros(0)
    end = min(args.hours * 3600.0, max(marks) + args.tail + 1.0)
    # the whole day, as bench_day runs it: the simulator sets its noise from the fan's
    # power over the whole run, and a shorter one is a different day
    for xs, _ in sim.chunks(args.hours * 3600.0):
        if pos / fs >= end:
            break
        for p in pending:
            p["audio"].append(xs)
        buf = np.concatenate([buf, xs])
        n = len(buf) // pri
        for i in range(n):
            if marks and pos / fs >= marks[0] - args.lead:
                # its audio: the rest of this chunk's pulses on, then every later chunk
                pending.append({"at": marks.pop(0), "pos": pos, "live": pickle.dumps(live),
                                "audio": [buf[i * pri:]], "schedule": sch,
                                "drift_ppm": drift})
            live.push(buf[i * pri:(i + 1) * pri], pos)
            live.take_events()
            pos += pri
        buf = buf[n * pri:]
        for p in [p for p in pending if pos / fs >= p["at"] + args.tail]:
            pending.remove(p)
            p["audio"] = np.concatenate(p["audio"])
            f = out / f"seed{args.seed}_{p['at']:g}.pkl"
            f.write_bytes(pickle.dumps(p))
            print(f"saved {f}", file=sys.stderr)
        print(f"\r{pos / fs / 60:6.1f} of {end / 60:.0f} simulated minutes", end="",
              file=sys.stderr, flush=True)
    print(file=sys.stderr)


def _hz(an: Any, cpp: float) -> float:
    """Blade cycles per pulse as Hz."""
    return cpp / an.ref.cycles_per_pulse * float(an.ref.meta["rate_hz"])


def replay(args: argparse.Namespace) -> None:
    snap = pickle.loads(Path(args.snap).read_bytes())
    live: LiveAnalyzer = pickle.loads(snap["live"])
    sch: Schedule = snap["schedule"]
    pri, fs = live.pri, live.cfg.audio.sample_rate
    audio, pos = snap["audio"], snap["pos"]
    t_from = args.t_from if args.t_from is not None else -math.inf
    t_to = args.t_to if args.t_to is not None else math.inf
    last_id: Any = None
    for i in range(len(audio) // pri):
        live.push(audio[i * pri:(i + 1) * pri], pos)
        pos += pri
        an = live.analyzer
        t = pos / fs
        if an is None or an.state is None or not t_from <= t <= t_to:
            live.take_events()
            continue
        tr = an.tracker
        ident = tr.identity
        note = ""
        if ident != last_id:
            note = f" NEW TRACK {ident}"
            last_id = ident
        for e in live.take_events():
            note += f" EVENT {e.kind} ({e.direction}, {e.rate_hz})"
        d, s = an.decided, an.state
        if an._since != 0 and not note and not args.every_pulse:
            continue
        truth = float(sch.rate_at(np.array([true_time(t, snap["drift_ppm"])]))[0])
        trk = "-" if tr.x is None else f"{_hz(an, float(tr.x[1])):+.3f}"
        fol = "-" if tr.fx is None else f"{_hz(an, float(tr.fx[1])):+.3f}"
        tz = an.transitions
        print(f"{t:9.2f} true {truth:+.3f} | dec {d.direction[:4]:4s} "
              f"{(d.rate_hz or 0):.3f} | pub {s.direction[:4]:4s} {(s.rate_hz or 0):.3f} | "
              f"trk {trk} fol {fol} w {tr.follower_weight:.2f} bound "
              f"{_hz(an, tr.rate_bound):.2f} | known {tz.known} zero_by "
              f"{'-' if tz._zero_by is None else f'{tz._zero_by:.1f}'} | coast "
              f"{tr.coasted} out {tr.outliers} upd {tr.updates} | still "
              f"{an.still.statistic()[0]:.3f}/{an._decide_settings.still_threshold:.3f}"
              f"{' frozen' if an.static.frozen else ''}{note}"
              + (f"\n{'':12s}{s.reason[:150]}" if args.reasons else ""))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="tools/trace_day.py")
    sub = ap.add_subparsers(dest="cmd", required=True)
    sv = sub.add_parser("save", help="run a day and save the pipeline before each moment")
    sv.add_argument("--hours", type=float, default=1.0)
    sv.add_argument("--seed", type=int, default=1)
    sv.add_argument("--random-scene", action="store_true",
                    help="the seed names a random scene (bench_day --random-scenes)")
    sv.add_argument("--at", type=float, nargs="+", required=True, help="stream times (s)")
    sv.add_argument("--lead", type=float, default=25.0, help="saved this long before (s)")
    sv.add_argument("--tail", type=float, default=10.0, help="audio kept after (s)")
    sv.add_argument("--out", required=True, help="folder of the saved moments")
    rp = sub.add_parser("replay", help="replay a saved moment with the internals printed")
    rp.add_argument("snap")
    rp.add_argument("--from", dest="t_from", type=float)
    rp.add_argument("--to", dest="t_to", type=float)
    rp.add_argument("--every-pulse", action="store_true", help="a line per pulse")
    rp.add_argument("--reasons", action="store_true", help="the published reason too")
    args = ap.parse_args(argv)
    (save if args.cmd == "save" else replay)(args)


if __name__ == "__main__":
    main()
