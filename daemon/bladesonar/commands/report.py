"""``bladesonar report``: accuracy of the answer against run time, on simulated scenes.

The edge of :mod:`bladesonar.runtime_report`: load scenes and config, build the references
and run the trials in worker processes (``--jobs``, 2 by default), then write
DIR/report.md, DIR/report.json (every aggregated number), DIR/trials.jsonl (every trial)
and the PNG curves (matplotlib, the ``plots`` extra).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from multiprocessing.pool import Pool

    from ..config import Config
    from ..reference_build import Reference
    from ..runtime_report import Grid, Job

EPILOG = """\
The full sweep (observation window 0.25-30 s, SNR -5..30 dB, rate ratios 0..9, 3-5 blades,
4 rooms, reversals, and the latency of started/stopped/reversed events on ramped
transitions at 0-60 dB) takes a few minutes on 2 cores; --quick is a small version for CI.
A custom sweep: --grid GRID.json with {"families": [{"name": ..., "scenes": [...],
"blades": [...], "ratios": [...], "snrs_db": [...], "windows_s": [...], "seeds": N,
"reversal": false, "transitions": false}, ...], "ref_seconds": 20, ...} (fields of
runtime_report.Grid). A family with "transitions": true ignores windows_s and runs
"transitions_schedule" (default "stop:0:6,{d}:{r}:14~5,stop:0:14~8,{d}:{r}:12~4,
{o}:{r}:16~10": {r} = ratio x ref_rate_hz, {d} its direction, {o} the other) with
"transitions_drift_ppm" (default 40) of clock drift, scoring each event against the truth.

examples:
  bladesonar report --quick --out out/report
  tools/error_vs_runtime --out docs/report-run --jobs 2
"""


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("report", help="accuracy against observation time, SNR, rate, blades "
                       "and room, and event latency against SNR, on simulated scenes "
                       "(Markdown, JSON, PNG)",
                       description="Measure direction accuracy, rate error, reversal "
                       "detection time, the latency of started/stopped/reversed events "
                       "against SNR and compute time of the analysis on simulated "
                       "recordings with known truth.", epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the report files")
    p.add_argument("--quick", action="store_true", help="the small sweep (under a minute)")
    p.add_argument("--grid", metavar="GRID.json", help="a custom sweep (see below)")
    p.add_argument("--jobs", type=int, default=2, metavar="N",
                   help="worker processes (default 2)")
    p.add_argument("--config", metavar="CFG", help="YAML config (default: built-in defaults)")
    p.add_argument("--scenes", metavar="DIR",
                   help="folder of the scene files (default: the repository's config/scenes)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG curves")
    p.set_defaults(func=run)


_STATE: dict[str, Any] = {}


def _init(state: dict[str, Any]) -> None:
    import logging

    logging.getLogger("bladesonar.sim").setLevel(logging.ERROR)
    _STATE.update(state)


def _ref_task(key: tuple[str, int]) -> tuple[tuple[str, int], Reference, float]:
    import time

    from ..runtime_report import make_reference

    scene, k = key
    t0 = time.process_time()
    ref = make_reference(_STATE["scenes"][scene], _STATE["cfg"], k, _STATE["grid"])
    return key, ref, time.process_time() - t0


def _job_task(job: Job) -> list[dict[str, Any]]:
    from ..runtime_report import run_airflow_job, run_job

    if job.airflow:
        return run_airflow_job(job)
    return run_job(job, _STATE["scenes"][job.scene], _STATE["cfg"],
                   _STATE["refs"][(job.scene, job.blades)], _STATE["grid"])


def _pool(n: int, state: dict[str, Any]) -> Pool:
    import multiprocessing as mp

    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    return ctx.Pool(n, initializer=_init, initargs=(state,))


def _tuples(fam: dict[str, Any]) -> dict[str, Any]:
    """A sweep file's family with its lists as the tuples :class:`Family` holds."""
    return {k: (tuple(v) if isinstance(v, list) else v) for k, v in fam.items()}


def load_grid(path: str) -> Grid:
    import dataclasses

    from ..errors import ConfigError
    from ..runtime_report import Family, Grid

    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
        fams = tuple(Family(**_tuples(fam)) for fam in data.pop("families"))
        return dataclasses.replace(Grid(families=fams), **data)
    except (OSError, ValueError, TypeError, KeyError) as exc:
        raise ConfigError("--grid", path, f"is not a valid sweep file ({exc}); see "
                          "'bladesonar report --help'") from exc


def _scenes_dir(args: argparse.Namespace, cfg: Config) -> Path:
    if args.scenes:
        return Path(args.scenes)
    mine = cfg.path("scenes")
    if args.config and mine.is_dir():
        return mine
    return Path(__file__).resolve().parents[3] / "config" / "scenes"


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from ..errors import ConfigError
    from ..io.config_file import load_config
    from ..io.scene_file import load_scene
    from ..runtime_report import (
        aggregate,
        aggregate_airflow,
        aggregate_reversals,
        aggregate_transitions,
        default_grid,
        envelope,
        limit_notes,
        refusal_notes,
    )

    if args.jobs < 1:
        raise ConfigError("--jobs", args.jobs, "must be at least 1")
    if not args.no_plots:
        from ..plots import pyplot

        pyplot()  # a missing matplotlib is said before minutes of work
    cfg = load_config(args.config)
    grid = load_grid(args.grid) if args.grid else default_grid(args.quick)
    sdir = _scenes_dir(args, cfg)
    scenes = {name: load_scene(sdir / f"{name}.yaml") for name in grid.scenes}
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError("--out", str(out), f"cannot be created ({exc.strerror})") from exc

    ref_info, records, wall = _sweep(args.jobs, dict(scenes=scenes, cfg=cfg, grid=grid))
    rows = aggregate(records)
    env = envelope(rows)
    rep = dict(format="bladesonar-report/1", meta=_meta(args, cfg, grid, records, wall),
               grid=dataclasses.asdict(grid), envelope=env,
               limits=limit_notes(rows, cfg.prf_hz, cfg.tracking.slew_limit,
                                  grid.ref_rate_hz) + refusal_notes(records),
               references=ref_info, rows=rows, reversals=aggregate_reversals(records),
               transitions=aggregate_transitions(records),
               airflow=aggregate_airflow(records))
    _write(out, rep, records, plots=not args.no_plots)
    print(json.dumps(dict(out=str(out), trials=len(records), wall_s=round(wall, 1),
                          envelope=env)))
    return 0


def _sweep(n_jobs: int, state: dict[str, Any]) -> tuple[dict[str, Any], list[dict[str, Any]],
                                                         float]:
    """The references of the grid, then every trial, on ``n_jobs`` processes: the
    references' figures by 'scene, K', the trials' records and the wall time, s."""
    import time

    from ..progress import Progress
    from ..runtime_report import jobs

    grid = state["grid"]
    t_wall = time.perf_counter()
    todo = jobs(grid)
    refkeys = grid.references()
    prog = Progress("report", len(todo) + len(refkeys), " jobs")
    done = 0
    refs, ref_info = {}, {}
    with _pool(n_jobs, state) as pool:
        for key, ref, cpu in pool.imap_unordered(_ref_task, refkeys):
            refs[key] = ref
            m = ref.meta
            ref_info[f"{key[0]}, {key[1]}"] = dict(rate_hz=float(m["rate_hz"]),
                                                   quality=float(m["quality"]),
                                                   gate_m=list(m["gate_m"]), cpu_s=cpu)
            done += 1
            prog.update(done)
    state["refs"] = refs
    records: list[dict[str, Any]] = []
    with _pool(n_jobs, state) as pool:
        for recs in pool.imap_unordered(_job_task, todo):
            records.extend(recs)
            done += 1
            prog.update(done)
    prog.close()
    return ref_info, records, time.perf_counter() - t_wall


def _meta(args: argparse.Namespace, cfg: Config, grid: Grid, records: list[dict[str, Any]],
          wall: float) -> dict[str, Any]:
    """How the report was made: the command, the machine, the costs, the grid's settings."""
    import datetime
    import os

    from ..runtime_report import TRANSITION_TARGETS_S, jobs

    cmd = "bladesonar report " + " ".join(sys.argv[2:]) if len(sys.argv) > 1 and \
        sys.argv[1] == "report" else "bladesonar report" + (" --quick" if args.quick else "")
    return dict(command=os.environ.get("BLADESONAR_REPORT_COMMAND", cmd),
                date=datetime.datetime.now().strftime("%Y-%m-%d %H:%M"),
                cpus=os.cpu_count(), jobs=args.jobs, wall_s=round(wall, 2),
                cpu_s=round(sum(r["cpu_s"] for r in records), 2), trials=len(records),
                ref_rate_hz=grid.ref_rate_hz, ref_seconds=grid.ref_seconds,
                ref_snr_db=grid.ref_snr_db, reversal_at_s=grid.reversal_at_s,
                reversal_seconds=grid.reversal_seconds, daemon_window_s=cfg.daemon.window_s,
                transitions_schedule=grid.transitions_schedule,
                transitions_drift_ppm=grid.transitions_drift_ppm,
                transition_targets_s=TRANSITION_TARGETS_S,
                prf_hz=cfg.prf_hz, aliasing_limit_hz_by_blades={
                    str(k): cfg.prf_hz / (2 * k) for k in sorted({j.blades
                                                                  for j in jobs(grid)})})


def _write(out: Path, rep: dict[str, Any], records: list[dict[str, Any]], *,
           plots: bool) -> None:
    """report.json, trials.jsonl (sorted), the plots and report.md into ``out``."""
    from ..report_text import markdown

    rows = rep["rows"]
    images = {}
    if plots:
        from ..plots import report as rp

        if any(r["family"] == "window_snr" for r in rows):
            rp.error_vs_time(rows, out / "error_vs_time.png")
            images["error against observation time"] = "error_vs_time.png"
        if any((r.get("window_s") or 0) > 0 and (r.get("cpu_per_audio_s") or 0) > 0
               for r in rows):
            # a sweep of transitions alone has no windows: that plot would be empty
            rp.compute_vs_window(rows, out / "compute_vs_window.png")
            images["compute time against window"] = "compute_vs_window.png"
    (out / "report.json").write_text(json.dumps(rep, indent=1, sort_keys=True) + "\n",
                                     encoding="utf-8")
    with open(out / "trials.jsonl", "w", encoding="utf-8") as f:
        for r in sorted(records, key=lambda r: (r["family"], r["scene"], r["blades"],
                                                r["ratio"], r["snr_db"],
                                                r.get("window_s", r.get("seconds", 0)),
                                                r["seed"], r.get("segment", 0))):
            f.write(json.dumps(r, sort_keys=True) + "\n")
    (out / "report.md").write_text(markdown(rep, images=images), encoding="utf-8")
