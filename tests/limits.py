"""Run a command under hard resource limits and measure it (the fuzz and nasty-file tests).

The limits are what make a test of hostile input safe and able to fail: a command that
would blow up is stopped by the kernel (RLIMIT_AS: address space; RLIMIT_CPU: CPU
seconds) instead of taking the machine down, and the test sees a signal, not exit 2.
The peak RSS comes from wait4() on that one child.
"""

from __future__ import annotations

import os
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

#: Address space a command may map. numpy, scipy and OpenBLAS map far more virtual memory
#: than they touch, so this is above the 200 MiB RSS bound that the tests assert.
AS_LIMIT = 1536 << 20
#: CPU seconds before the kernel stops a command (SIGXCPU), and the RSS bound, MiB.
CPU_LIMIT_S = 10
RSS_LIMIT_MIB = 200.0


@dataclass
class Measured:
    args: list[str]
    returncode: int
    stdout: str
    stderr: str
    seconds: float
    peak_rss_mib: float


def run_limited(args: list[str], *, cwd: str | Path | None = None, env: dict | None = None,
                as_limit: int = AS_LIMIT, cpu_limit_s: int = CPU_LIMIT_S,
                wall_limit_s: float = 60.0) -> Measured:
    """Run ``args`` with RLIMIT_AS and RLIMIT_CPU set in the child; a wall-clock timer
    only guards against a hang (it kills; the caller asserts on the exit status).

    The limits are set by the shell's ``ulimit`` before it execs the command (same pid,
    so wait4 measures the command), not by ``preexec_fn``, which is unsafe when the
    caller runs several of these from threads."""
    limited = ["/bin/sh", "-c", f'ulimit -v {as_limit // 1024} && ulimit -t {cpu_limit_s} '
               '&& exec "$@"', "limited", *args]
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        t0 = time.monotonic()
        p = subprocess.Popen(limited, stdout=out, stderr=err, stdin=subprocess.DEVNULL,
                             cwd=cwd, env=env)
        timer = threading.Timer(wall_limit_s, p.kill)
        timer.start()
        try:
            _, status, ru = os.wait4(p.pid, 0)
        finally:
            timer.cancel()
        seconds = time.monotonic() - t0
        p.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        return Measured(list(args), p.returncode, out.read().decode("utf-8", "replace"),
                        err.read().decode("utf-8", "replace"), seconds,
                        ru.ru_maxrss / 1024.0)
