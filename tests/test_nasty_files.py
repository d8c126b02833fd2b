"""The CLI on a corpus of hostile files (tools/make-nasty-files): every one must give the
documented exit status (2; 78 for ``run``'s config), exactly one error line and no
traceback, within RLIMIT_CPU and RLIMIT_AS, with a peak RSS under 200 MiB, and leave no
file behind. The numbers are docs/reliability.md's promises, not what the code happens
to do: a loader that crashes, loops, or reads a bomb fails here."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from limits import RSS_LIMIT_MIB, Measured, run_limited
from loopback import ROOT, bladesonar_cmd

pytestmark = pytest.mark.slow

#: Longest error line a user may get, characters (paths included).
MAX_ERROR_LINE = 800


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("nasty")
    r = subprocess.run([str(ROOT / "tools" / "make-nasty-files"), str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    counts = json.loads(r.stdout)
    assert counts["reference"] >= 60 and counts["wav"] >= 20 and counts["config"] >= 15
    return out


def _env() -> dict:
    env = dict(os.environ)
    env.pop("NOTIFY_SOCKET", None)
    return env


def _problems(m: Measured, want_rc: int, command: str) -> list[str]:
    """What is wrong with one run, against the documented behaviour."""
    bad = []
    what = " ".join(Path(a).name if "/" in a else a for a in m.args[3:])
    if m.returncode != want_rc:
        bad.append(f"{what}: exit {m.returncode}, documented {want_rc}: {m.stderr[-300:]}")
    if "Traceback" in m.stderr:
        bad.append(f"{what}: traceback: {m.stderr[-500:]}")
    errors = [ln for ln in m.stderr.splitlines() if ln.startswith(f"bladesonar {command}: ")]
    if len(errors) != 1:
        bad.append(f"{what}: {len(errors)} error lines: {m.stderr[-300:]}")
    elif len(errors[0]) > MAX_ERROR_LINE:
        bad.append(f"{what}: error line of {len(errors[0])} characters")
    if m.peak_rss_mib > RSS_LIMIT_MIB:
        bad.append(f"{what}: peak RSS {m.peak_rss_mib:.0f} MiB")
    return bad


def _run_all(jobs: list[tuple[list[str], int, str]]) -> tuple[list[str], list[Measured]]:
    env = _env()
    with ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 2)) as ex:
        results = list(ex.map(lambda j: run_limited(j[0], cwd=ROOT, env=env), jobs))
    problems = [p for (_, rc, cmd), m in zip(jobs, results, strict=True)
                for p in _problems(m, rc, cmd)]
    return problems, results


def _report(name: str, results: list[Measured]) -> None:
    worst = max(results, key=lambda m: m.peak_rss_mib)
    slow = max(results, key=lambda m: m.seconds)
    def what(m: Measured) -> str:
        return " ".join(Path(a).name for a in m.args[3:])

    print(f"\n{name}: {len(results)} runs; peak RSS {worst.peak_rss_mib:.0f} MiB "
          f"({what(worst)}), slowest {slow.seconds:.2f} s ({what(slow)})", file=sys.stderr)


def test_the_seeds_are_valid(corpus, tmp_path):
    """The nasty files are made from these; they must work, or the rest proves nothing."""
    g = corpus / "good"
    r = subprocess.run(bladesonar_cmd("analyze", "--config", str(g / "good.yaml"),
                                      "--reference", str(g / "good.npz"), str(g / "good.wav")),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["direction"] == "same"
    r = subprocess.run(bladesonar_cmd("simulate", "--scene", str(g / "good-scene.yaml"),
                                      "--seconds", "0.5", "--out", str(tmp_path / "s.wav"),
                                      "--quiet"), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr


def test_bad_references_exit_2_in_one_line(corpus):
    g = corpus / "good"
    jobs = [(bladesonar_cmd("analyze", "--reference", str(f), str(g / "good.wav")), 2,
             "analyze") for f in sorted((corpus / "reference").iterdir())]
    problems, results = _run_all(jobs)
    _report("references", results)
    assert not problems, "\n".join(problems)


def test_bad_wavs_exit_2_in_one_line(corpus, tmp_path):
    g = corpus / "good"
    files = sorted((corpus / "wav").iterdir())
    jobs = [(bladesonar_cmd("analyze", "--reference", str(g / "good.npz"), str(f)), 2,
             "analyze") for f in files]
    jobs += [(bladesonar_cmd("reference", "--direction", "ccw", "--out",
                             str(tmp_path / f"{f.stem}.npz"), str(f)), 2, "reference")
             for f in files if f.name in ("sixty-one-minutes.wav", "data-lies-huge.wav",
                                          "spliced.wav", "zero-channels.wav",
                                          "huge-list-chunk.wav")]
    problems, results = _run_all(jobs)
    _report("wavs", results)
    assert not problems, "\n".join(problems)
    assert list(tmp_path.iterdir()) == []


def test_bad_configs_exit_2_and_run_exits_78(corpus):
    files = sorted((corpus / "config").iterdir())
    jobs = [(bladesonar_cmd("check-config", "--config", str(f)), 2, "check-config")
            for f in files]
    # run reads the config with the same loader: the cases that used to exit 1 or
    # exhaust memory there (a restart loop under systemd) are enough
    jobs += [(bladesonar_cmd("run", "--config", str(f), "--seconds", "1"), 78, "run")
             for f in files if f.stem in ("latin1", "billion-laughs", "deep-flow",
                                          "oversized", "huge-int", "a-directory",
                                          "huge-string", "python-object")]
    problems, results = _run_all(jobs)
    _report("configs", results)
    assert not problems, "\n".join(problems)


def test_bad_scenes_exit_2_in_one_line(corpus, tmp_path):
    jobs = [(bladesonar_cmd("simulate", "--scene", str(f), "--seconds", "1", "--out",
                            str(tmp_path / "x.wav")), 2, "simulate")
            for f in sorted((corpus / "scene").iterdir())]
    problems, results = _run_all(jobs)
    _report("scenes", results)
    assert not problems, "\n".join(problems)
    assert list(tmp_path.iterdir()) == []


def test_the_daemon_publishes_an_invalid_reference_and_keeps_running(corpus, tmp_path):
    """``run`` with a corrupt reference in its state folder: a retained state
    ``reference_invalid`` with the reason, an event, no traceback, and it runs until told
    to stop (exit 0), never exit 1 (systemd would restart it every 5 s for ever)."""
    names = ["truncated-5.npz", "bitflip-3.npz", "zip-bomb.npz", "npy-huge-shape.npz",
             "meta-rate-nan.npz", "table-nan.npz", "meta-depends-rate-zero.npz",
             "checksum-mismatch.npz", "meta-deep-json.npz", "random-bytes.npz"]
    jobs = []
    for name in names:
        state = tmp_path / name / "state"
        state.mkdir(parents=True)
        shutil.copy(corpus / "reference" / name, state / "reference.npz")
        cfg = tmp_path / name / "cfg.yaml"
        cfg.write_text(json.dumps({"audio": {"backend": "sim"},
                                   "daemon": {"state_dir": str(state)},
                                   "sim": {"scene": str(ROOT / "config" / "scenes" /
                                                        "paper-room.yaml")}}))
        jobs.append(bladesonar_cmd("run", "--config", str(cfg), "--seconds", "1.5"))
    env = _env()
    with ThreadPoolExecutor(max_workers=2) as ex:
        results = list(ex.map(lambda a: run_limited(a, cwd=ROOT, env=env), jobs))
    bad = []
    for name, m in zip(names, results, strict=True):
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
    assert not bad, "\n".join(bad)
