"""The command line runs numpy's BLAS single-threaded unless the user says otherwise:
the report's workers (one per core) and the daemon's loop beside its audio threads only
lose to BLAS thread pools (2 report workers: 112 ms of CPU per 1 s trial instead of 6).
Checked against what the loaded OpenBLAS itself reports."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

CODE = """
import ctypes, glob, os
import bladesonar.blas as c
c.single_threaded_blas()            # what cli.main() does first
import numpy
libs = glob.glob(os.path.join(os.path.dirname(numpy.__file__) + ".libs", "*openblas*.so*"))
lib = ctypes.CDLL(libs[0]) if libs else None
f = lib and next((getattr(lib, n) for n in ("scipy_openblas_get_num_threads64_",
                                            "openblas_get_num_threads64_",
                                            "openblas_get_num_threads") if hasattr(lib, n)), None)
print(f() if f else -1)
"""


def _threads(**kw) -> int:
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    env.update(kw)
    out = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True,
                         env=env, check=True).stdout
    return int(out.strip())


def test_blas_runs_one_thread_and_a_user_setting_wins():
    if (os.cpu_count() or 1) < 2:
        pytest.skip("one CPU: OpenBLAS starts one thread anyway")
    got = _threads()
    if got == -1:
        pytest.skip("numpy is not linked with its bundled OpenBLAS here")
    assert got == 1
    assert _threads(OPENBLAS_NUM_THREADS="2") == 2
