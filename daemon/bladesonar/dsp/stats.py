"""``np.median`` without ``numpy.ma`` (pure numpy).

numpy's median checks its result for NaNs through ``np.ma.isMaskedArray``, and the first
call imports the whole masked-array package: 1.9 MiB of resident memory in the daemon,
for a check that never applies to a plain array. :func:`median` is numpy's algorithm
(``np.partition`` on the middle one or two elements and the last, their mean, NaN if the
data hold one) for plain arrays, so it gives the same values bit for bit.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def median(a: np.ndarray, axis: int | None = None) -> Any:
    """``np.median(a, axis=axis)`` for a plain array (no ``out``, no ``keepdims``): a
    numpy scalar without an axis, an array with one, as numpy's."""
    a = np.asarray(a)
    if axis is None:
        a, axis = a.ravel(), 0
    n = a.shape[axis]
    if n == 0:
        return np.median(a, axis=axis)   # numpy's warning and NaN (never in the daemon)
    half = n // 2
    kth = [half - 1, half] if n % 2 == 0 else [half]
    nans = a.dtype.kind in "fc"
    part = np.partition(a, kth + [-1] if nans else kth, axis=axis)
    index = [slice(None)] * part.ndim
    index[axis] = slice(half - 1, half + 1) if n % 2 == 0 else slice(half, half + 1)
    out = np.mean(part[tuple(index)], axis=axis)
    if nans:
        last = part.take(-1, axis=axis)
        isnan = np.isnan(last)
        if isnan.any():
            if isinstance(out, np.generic):
                return last
            np.copyto(out, last, where=isnan)
    return out
