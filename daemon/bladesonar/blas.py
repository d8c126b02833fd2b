"""numpy's BLAS kept to one thread: its thread pools only cost here (the matrices are small,
the report runs one worker per core and the daemon runs beside its audio threads). On the
ground floor so that the command line and the benchmarks in tools/ set it the same way."""

from __future__ import annotations

import os

#: Measured on 2 cores: two report workers with OpenBLAS's default threads took 112 ms of
#: CPU per 1 s trial, 6 ms with one.
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def single_threaded_blas() -> None:
    """Default the BLAS libraries to one thread (a value set by the user wins); effective
    only before numpy is first imported, which the commands do lazily."""
    for var in BLAS_THREAD_VARS:
        os.environ.setdefault(var, "1")
