"""The CLI runs on the nasty-file corpus (tools/make-nasty-files) and what each must do:
shared by tests/test_nasty_files.py (which asserts it) and tools/nasty-bounds (which
measures the same runs one at a time: peak RSS, CPU and wall time)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from limits import RSS_LIMIT_MIB, Measured
from loopback import ROOT, bladesonar_cmd

#: Longest error line a user may get, characters (paths included).
MAX_ERROR_LINE = 800

#: One run: the command line, its documented exit status, the command's name.
Job = tuple[list[str], int, str]

#: Bad WAVs that ``reference`` also reads (the ones that used to crash it or blow up).
REFERENCE_WAVS = ("sixty-one-minutes.wav", "data-lies-huge.wav", "spliced.wav",
                  "zero-channels.wav", "huge-list-chunk.wav")
#: Bad configs that ``run`` also reads (the cases that used to exit 1 or exhaust memory
#: there: a restart loop under systemd); it reads them with the same loader.
RUN_CONFIGS = ("latin1", "billion-laughs", "deep-flow", "oversized", "huge-int",
               "a-directory", "huge-string", "python-object")
#: Corrupt references the daemon gets in its state folder.
DAEMON_REFERENCES = ("truncated-5.npz", "bitflip-3.npz", "zip-bomb.npz",
                     "npy-huge-shape.npz", "meta-rate-nan.npz", "table-nan.npz",
                     "meta-depends-rate-zero.npz", "checksum-mismatch.npz",
                     "meta-deep-json.npz", "random-bytes.npz")


def reference_jobs(corpus: Path) -> list[Job]:
    g = corpus / "good"
    return [(bladesonar_cmd("analyze", "--reference", str(f), str(g / "good.wav")), 2,
             "analyze") for f in sorted((corpus / "reference").iterdir())]


def wav_jobs(corpus: Path, out: Path) -> list[Job]:
    """``analyze`` on every bad WAV, ``reference`` (writing into ``out``) on some."""
    g = corpus / "good"
    files = sorted((corpus / "wav").iterdir())
    jobs: list[Job] = [(bladesonar_cmd("analyze", "--reference", str(g / "good.npz"),
                                       str(f)), 2, "analyze") for f in files]
    jobs += [(bladesonar_cmd("reference", "--direction", "ccw", "--out",
                             str(out / f"{f.stem}.npz"), str(f)), 2, "reference")
             for f in files if f.name in REFERENCE_WAVS]
    return jobs


def config_jobs(corpus: Path) -> list[Job]:
    files = sorted((corpus / "config").iterdir())
    jobs: list[Job] = [(bladesonar_cmd("check-config", "--config", str(f)), 2,
                        "check-config") for f in files]
    jobs += [(bladesonar_cmd("run", "--config", str(f), "--seconds", "1"), 78, "run")
             for f in files if f.stem in RUN_CONFIGS]
    return jobs


def scene_jobs(corpus: Path, out: Path) -> list[Job]:
    return [(bladesonar_cmd("simulate", "--scene", str(f), "--seconds", "1", "--out",
                            str(out / "x.wav")), 2, "simulate")
            for f in sorted((corpus / "scene").iterdir())]


def daemon_jobs(corpus: Path, work: Path) -> list[tuple[str, list[str]]]:
    """(name, ``run`` for 1.5 s with that corrupt reference in its state folder)."""
    jobs = []
    for name in DAEMON_REFERENCES:
        state = work / name / "state"
        state.mkdir(parents=True)
        shutil.copy(corpus / "reference" / name, state / "reference.npz")
        cfg = work / name / "cfg.yaml"
        cfg.write_text(json.dumps({"audio": {"backend": "sim"},
                                   "daemon": {"state_dir": str(state)},
                                   "sim": {"scene": str(ROOT / "config" / "scenes" /
                                                        "paper-room.yaml")}}))
        jobs.append((name, bladesonar_cmd("run", "--config", str(cfg), "--seconds", "1.5")))
    return jobs


def long_recording_job(work: Path) -> Job:
    """``reference`` on a recording of the fan longer than it reads (it uses the first
    2^20 samples, 23.8 s at 44.1 kHz, with a warning): the most memory a reference can
    cost. Valid input: exit 0."""
    from bladesonar import config
    from bladesonar.io.scene_file import load_scene
    from bladesonar.io.wav import WavWriter
    from bladesonar.sim.render import simulate
    from bladesonar.sim.schedule import Schedule

    x, _ = simulate(load_scene(ROOT / "config" / "scenes" / "paper-room.yaml"),
                    config.Config(), 25.0, schedule=Schedule.constant(0.45, "ccw"),
                    snr_db=20.0, seed=7)
    wav = work / "twenty-five-seconds.wav"
    with WavWriter(wav, 44100) as w:
        w.write(x)
    return (bladesonar_cmd("reference", "--direction", "ccw", "--out",
                           str(work / "long.npz"), str(wav)), 0, "reference")


def what(m: Measured) -> str:
    """A run in a few words: the command and the file names."""
    return " ".join(Path(a).name if "/" in a else a for a in m.args[3:])


def problems(m: Measured, want_rc: int, command: str) -> list[str]:
    """What is wrong with one run, against the documented behaviour."""
    bad = []
    w = what(m)
    if m.returncode != want_rc:
        bad.append(f"{w}: exit {m.returncode}, documented {want_rc}: {m.stderr[-300:]}")
    if "Traceback" in m.stderr:
        bad.append(f"{w}: traceback: {m.stderr[-500:]}")
    errors = [ln for ln in m.stderr.splitlines() if ln.startswith(f"bladesonar {command}: ")]
    if len(errors) != 1:
        bad.append(f"{w}: {len(errors)} error lines: {m.stderr[-300:]}")
    elif len(errors[0]) > MAX_ERROR_LINE:
        bad.append(f"{w}: error line of {len(errors[0])} characters")
    if m.peak_rss_mib > RSS_LIMIT_MIB:
        bad.append(f"{w}: peak RSS {m.peak_rss_mib:.0f} MiB")
    return bad


def valid_problems(m: Measured) -> list[str]:
    """A valid input at a limit: exit 0, no traceback, within the memory bound."""
    bad = []
    if m.returncode != 0 or "Traceback" in m.stderr:
        bad.append(f"{what(m)}: exit {m.returncode}: {m.stderr[-400:]}")
    if m.peak_rss_mib > RSS_LIMIT_MIB:
        bad.append(f"{what(m)}: peak RSS {m.peak_rss_mib:.0f} MiB")
    return bad


def daemon_problems(name: str, m: Measured) -> list[str]:
    """``run`` with a corrupt reference: a retained state ``reference_invalid`` with the
    reason, one event, no traceback, exit 0 when its time is up."""
    bad = []
    msgs = [json.loads(ln) for ln in m.stdout.splitlines() if ln.startswith("{")]
    # (the first state says "starting": nothing known yet, never a previous run's)
    states = [x["payload"] for x in msgs if x["topic"].endswith("/state")
              and x["payload"]["status"] != "starting"]
    events = [x["payload"]["kind"] for x in msgs if x["topic"].endswith("/event")]
    if m.returncode != 0 or "Traceback" in m.stderr:
        bad.append(f"{name}: exit {m.returncode}: {m.stderr[-400:]}")
    elif not states or states[0]["status"] != "reference_invalid" \
            or "reference.npz" not in states[0].get("detail", ""):
        bad.append(f"{name}: states {states}")
    elif events != ["reference_invalid"]:
        bad.append(f"{name}: events {events}")
    if m.peak_rss_mib > RSS_LIMIT_MIB:
        bad.append(f"{name}: peak RSS {m.peak_rss_mib:.0f} MiB")
    return bad
