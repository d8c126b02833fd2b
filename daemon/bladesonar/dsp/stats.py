"""Small statistics the daemon needs without scipy or ``numpy.ma``.

``np.median`` without ``numpy.ma`` (pure numpy).

numpy's median checks its result for NaNs through ``np.ma.isMaskedArray``, and the first
call imports the whole masked-array package: 1.9 MiB of resident memory in the daemon,
for a check that never applies to a plain array. :func:`median` is numpy's algorithm
(``np.partition`` on the middle one or two elements and the last, their mean, NaN if the
data hold one) for plain arrays, so it gives the same values bit for bit.
"""

from __future__ import annotations

import math
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


def _beta_cf(a: float, b: float, x: float) -> float:
    """The continued fraction of the regularised incomplete beta (modified Lentz)."""
    tiny = 1e-300
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 300):
        for num in (m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
                    -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))):
            d = 1.0 + num * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + num / c
            c = c if abs(c) > tiny else tiny
            h *= d * c
        if abs(d * c - 1.0) < 1e-15:
            break
    return h


def t_tail(t: float, dof: float) -> float:
    """P(T > t) for Student's t with ``dof`` degrees of freedom (``0.5 I_x(dof/2, 1/2)``,
    ``x = dof / (dof + t^2)``), accurate in the far tail where ``1 - cdf`` is not."""
    if math.isnan(t) or not dof > 0:
        return math.nan
    if math.isinf(t):
        return 0.0 if t > 0 else 1.0
    a, b = 0.5 * dof, 0.5
    x = dof / (dof + t * t)
    lead = math.exp(math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b)
                    + a * math.log(x) + b * math.log1p(-x)) if 0.0 < x < 1.0 else 0.0
    if x == 1.0:
        half = 0.5
    elif x < (a + 1.0) / (a + b + 2.0):
        half = 0.5 * lead * _beta_cf(a, b, x) / a
    else:
        half = 0.5 * (1.0 - lead * _beta_cf(b, a, 1.0 - x) / b)
    return half if t >= 0 else 1.0 - half


def normal_tail_inverse(p: float) -> float:
    """The z with P(Z > z) = ``p`` for a standard normal Z (Newton on the log tail)."""
    if not 0.0 < p < 1.0:
        return math.inf if p <= 0.0 else -math.inf if p >= 1.0 else math.nan
    if p >= 0.5:
        return 0.0 if p == 0.5 else -normal_tail_inverse(1.0 - p)
    z = math.sqrt(-2.0 * math.log(p))
    z -= (2.515517 + 0.802853 * z + 0.010328 * z * z) / \
        (1.0 + 1.432788 * z + 0.189269 * z * z + 0.001308 * z ** 3)
    for _ in range(50):
        q = 0.5 * math.erfc(z / math.sqrt(2.0))
        if not q > 0.0:
            break
        phi = math.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
        step = (math.log(q) - math.log(p)) * q / phi
        z += step
        if abs(step) < 1e-12 * max(1.0, abs(z)):
            break
    return z


def t_as_z(t: float, dof: float) -> float:
    """The normal z of the same one-sided tail as Student's ``t`` with ``dof`` degrees of
    freedom: a t from a few batch means is heavy-tailed (P(T > 3) is 0.015 at 5 degrees
    of freedom, 0.0013 for a normal), so a threshold set as a normal significance is read
    on this scale. Sign kept; infinite for an infinite t."""
    if math.isnan(t):
        return math.nan
    if math.isinf(t):
        return t
    z = normal_tail_inverse(t_tail(abs(t), dof))
    return math.copysign(z, t) if t != 0 else 0.0
