"""Run a command under hard resource limits and measure it (the fuzz and nasty-file tests).

The limits are what make a test of hostile input safe and able to fail: a command that
would blow up is stopped by the kernel (RLIMIT_AS: address space; RLIMIT_CPU: CPU
seconds) instead of taking the machine down, and the test sees a signal, not exit 2.

The peak RSS and CPU time are the command's own: a small single-threaded wrapper forks
it, sets the limits in the child and reports wait4()'s ru_maxrss, ru_utime and ru_stime.
(A child forked straight from the test process would start its ru_maxrss at the test
process's peak, since Linux carries the forked memory's high-water mark across exec; and
preexec_fn is unsafe from threads.)
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

#: Address space a command may map. numpy, scipy and OpenBLAS map far more virtual memory
#: than they touch, so this is above the 200 MiB RSS bound that the tests assert.
AS_LIMIT = 1536 << 20
#: CPU seconds before the kernel stops a command (SIGKILL), and the RSS bound, MiB.
CPU_LIMIT_S = 10
RSS_LIMIT_MIB = 200.0

_WRAPPER = r"""
import os, resource, sys
report, as_limit, cpu = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
pid = os.fork()
if pid == 0:
    resource.setrlimit(resource.RLIMIT_AS, (as_limit, as_limit))
    resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu))
    os.execv(sys.argv[4], sys.argv[4:])
_, status, ru = os.wait4(pid, 0)
with open(report, "w") as f:
    f.write(f"{os.waitstatus_to_exitcode(status)} {ru.ru_maxrss} {ru.ru_utime + ru.ru_stime}")
"""


@dataclass
class Measured:
    args: list[str]
    returncode: int
    stdout: str
    stderr: str
    seconds: float
    peak_rss_mib: float
    cpu_s: float = 0.0


def run_limited(args: list[str], *, cwd: str | Path | None = None, env: dict | None = None,
                as_limit: int = AS_LIMIT, cpu_limit_s: int = CPU_LIMIT_S,
                wall_limit_s: float = 60.0) -> Measured:
    """Run ``args`` (args[0] an executable path) with RLIMIT_AS and RLIMIT_CPU; a
    wall-clock timer only guards against a hang (it kills the whole process group; the
    caller then sees returncode -9)."""
    with tempfile.TemporaryDirectory() as d:
        report = Path(d) / "report"
        out, err = Path(d) / "out", Path(d) / "err"
        with open(out, "wb") as fo, open(err, "wb") as fe:
            t0 = time.monotonic()
            p = subprocess.Popen([sys.executable, "-c", _WRAPPER, str(report), str(as_limit),
                                  str(cpu_limit_s), *args], stdout=fo, stderr=fe,
                                 stdin=subprocess.DEVNULL, cwd=cwd, env=env,
                                 start_new_session=True)
            timer = threading.Timer(wall_limit_s, lambda: os.killpg(p.pid, signal.SIGKILL))
            timer.start()
            try:
                p.wait()
            finally:
                timer.cancel()
            seconds = time.monotonic() - t0
        if report.exists():
            code, rss, cpu = report.read_text().split()
            rc, maxrss, cpu_s = int(code), int(rss), float(cpu)
        else:
            rc, maxrss, cpu_s = p.returncode, 0, 0.0
        return Measured(list(args), rc, out.read_text("utf-8", "replace"),
                        err.read_text("utf-8", "replace"), seconds, maxrss / 1024.0, cpu_s)
