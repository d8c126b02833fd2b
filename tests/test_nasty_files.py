"""The CLI on a corpus of hostile files (tools/make-nasty-files): every one must give the
documented exit status (2; 78 for ``run``'s config), exactly one error line and no
traceback, within RLIMIT_CPU and RLIMIT_AS, with a peak RSS under 200 MiB, and leave no
file behind. The numbers are docs/reliability.md's promises, not what the code happens
to do: a loader that crashes, loops, or reads a bomb fails here."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from limits import Measured, run_limited
from loopback import ROOT, bladesonar_cmd
from nasty import (
    Job,
    config_jobs,
    daemon_jobs,
    daemon_problems,
    long_recording_job,
    problems,
    reference_jobs,
    scene_jobs,
    valid_problems,
    wav_jobs,
    what,
)

pytestmark = pytest.mark.slow


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


def _run_all(jobs: list[Job]) -> tuple[list[str], list[Measured]]:
    env = _env()
    with ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 2)) as ex:
        results = list(ex.map(lambda j: run_limited(j[0], cwd=ROOT, env=env), jobs))
    bad = [p for (_, rc, cmd), m in zip(jobs, results, strict=True)
           for p in problems(m, rc, cmd)]
    return bad, results


def _report(name: str, results: list[Measured]) -> None:
    """With -s: the corpus's worst figures (two runs at a time; tools/nasty-bounds
    measures them one at a time)."""
    worst = max(results, key=lambda m: m.peak_rss_mib)
    slow = max(results, key=lambda m: m.seconds)
    cpu = max(results, key=lambda m: m.cpu_s)
    print(f"\n{name}: {len(results)} runs; peak RSS {worst.peak_rss_mib:.0f} MiB "
          f"({what(worst)}), slowest {slow.seconds:.2f} s ({what(slow)}), most CPU "
          f"{cpu.cpu_s:.2f} s ({what(cpu)})", file=sys.stderr)


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
    bad, results = _run_all(reference_jobs(corpus))
    _report("references", results)
    assert not bad, "\n".join(bad)


def test_bad_wavs_exit_2_in_one_line(corpus, tmp_path):
    bad, results = _run_all(wav_jobs(corpus, tmp_path))
    _report("wavs", results)
    assert not bad, "\n".join(bad)
    assert list(tmp_path.iterdir()) == []


def test_bad_configs_exit_2_and_run_exits_78(corpus):
    bad, results = _run_all(config_jobs(corpus))
    _report("configs", results)
    assert not bad, "\n".join(bad)


def test_bad_scenes_exit_2_in_one_line(corpus, tmp_path):
    bad, results = _run_all(scene_jobs(corpus, tmp_path))
    _report("scenes", results)
    assert not bad, "\n".join(bad)
    assert list(tmp_path.iterdir()) == []


def test_the_daemon_publishes_an_invalid_reference_and_keeps_running(corpus, tmp_path):
    """``run`` with a corrupt reference in its state folder: a retained state
    ``reference_invalid`` with the reason, an event, no traceback, and it runs until told
    to stop (exit 0), never exit 1 (systemd would restart it every 5 s for ever)."""
    jobs = daemon_jobs(corpus, tmp_path)
    env = _env()
    with ThreadPoolExecutor(max_workers=2) as ex:
        results = list(ex.map(lambda j: run_limited(j[1], cwd=ROOT, env=env), jobs))
    bad = [p for (name, _), m in zip(jobs, results, strict=True)
           for p in daemon_problems(name, m)]
    assert not bad, "\n".join(bad)


def test_a_reference_from_the_longest_recording_it_reads_stays_under_200_mib(tmp_path):
    """The memory bound holds for valid input too: ``reference`` on a recording longer
    than it reads (the first 23.8 s at 44.1 kHz are used) peaked at 200.4 MiB once the
    pulses were brought to a common gain (the doppler spectrum of all 780 features at
    once was 77 MiB of temporaries)."""
    args, rc, _ = long_recording_job(tmp_path)
    m = run_limited(args, cwd=ROOT, env=_env())
    assert not valid_problems(m), valid_problems(m)
    assert (tmp_path / "long.npz").is_file()
