"""tools/bench_day's random-scene options refuse what would mix the sets, with the fix
named (exit 2, argparse's), before any day is simulated."""

from __future__ import annotations

import subprocess

import pytest


@pytest.mark.parametrize("args, says", [
    (["--random-scenes", "2"], "--set tuning or --set held-out"),
    (["--random-scenes", "2", "--set", "held-out", "--first-seed", "5"],
     "belong to the tuning set"),
    (["--random-scenes", "2", "--set", "tuning", "--first-seed", "99999"],
     "belong to the held-out set"),
    (["--random-scenes", "-1", "--set", "tuning"], "give a number of scenes"),
    (["--random-scenes", "1", "--set", "tuning", "--jobs", "0"], "give 1 or more"),
    (["--dims", "3"], "--dims 3 needs --random-scenes"),
    (["--random-scenes", "1", "--set", "tuning", "--dims", "4"], "invalid choice"),
])
def test_bench_day_refuses_mixed_or_empty_sets(repo_root, args, says):
    run = subprocess.run([str(repo_root / "tools/bench_day"), *args], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 2
    assert says in run.stderr
