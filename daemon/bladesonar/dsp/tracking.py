"""Circular Kalman filter on (blade phase, phase rate) of the matched reference phases.

State ``x = [phase, rate]`` in cycles of the reference table (one blade period) and cycles
per pulse; constant-rate model ``F = [[1, 1], [0, 1]]`` with white rate noise. Phases live
on a circle, so the innovation is wrapped into [-1/2, 1/2) and the phase state is kept in
[0, 1). The covariance update is Joseph form plus symmetrisation, which keeps P symmetric
positive definite in stiff cases (tiny process noise, huge measurement noise, long runs).

Outliers: an innovation outside ``gate_sigma`` standard deviations, or larger than the
slew bound (the phase cannot move further than the largest allowed rate beyond what was
predicted) or than ``MAX_INNOVATION``, is skipped and counted; after ``reacquire_after``
outliers in a row the filter re-initialises from the recent matches. A track that has
shown its line coasts through weak matches instead (no blade in view:
:meth:`Tracker._coasts`).

Initialisation finds the rate sign robustly by circular regression: over candidate rates
w within the slew bound, the coherence ``|sum_k q_k exp(2 pi i (z_k - w k))| / sum q_k`` of
the first matches is largest at the true rate; random matches give a low coherence and
the filter stays unlocked (no answer) instead of guessing.

Beside the track a *rate follower* (three states: phase, rate, rate change) takes the
matches the track accepts; the reported rate is the follower's while the recent matches
favour its model (a likelihood ratio with forgetting), so ramps are followed through the
blind part of a blade period without the constant-rate model's lag. While the follower's
rate is reported, a match it refuses is an outlier for both; while the matches favour it
clearly, the track takes its line for a match only the follower expects. A track that the
recent good matches mostly reject is re-checked against the best line of those matches
(:meth:`Tracker.recheck`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import overload

import numpy as np

#: Pulses over which the track and the rate follower are compared (forgetting).
FOLLOW_MEMORY = 24.0
#: Follower weight above which the track takes the follower's line for a match only the
#: follower expects (Tracker._follower_takes). Higher than the 1/2 at which the
#: follower's rate is reported: near rest the follower can carry a spin-down's
#: deceleration through zero, and just after a lock it is the less certain line, so the
#: track follows it only when the matches clearly favour it (docs/dynamics.md, History).
SYNC_WEIGHT = 0.9
#: Clear matches over which the share of stray ones (Tracker.stray) is measured, and the
#: share assumed before any are seen.
STRAY_MEMORY = 64.0
STRAY_START = 0.05
#: Clear matches (quality min_info or more) the track must have rejected among the recent
#: ones before it is re-checked (Tracker.recheck).
RECHECK_REJECTED = 3
#: Largest rate change the follower keeps, as a multiple of the steepest ramp
#: (TrackerSettings.max_accel).
ACCEL_LIMIT = 2.0
#: Share of its own blade period a track coasts through weak matches after its last clear
#: one (Tracker._coasts): long enough for the blind part of a blade period (about half
#: in the paper room), short enough that a fan stopped with its blade out of view is
#: soon measured again rather than held turning.
COAST_SHARE = 0.6
#: Clear-match credit a track must hold before it may coast: each clear match (quality
#: min_info or more) it accepts adds one, up to COAST_CREDIT, and each it rejects takes
#: one away. A wrong first lock (a fast fan against a slow reference) rejects the clear
#: matches, never earns the credit, and its weak outliers give it up.
COAST_STREAK = 3
#: The follower's weight (Tracker.follower_weight) from which a match with a twin (a
#: look-alike angle: fingerprint.twin_bins) is read as the one the follower expects
#: rather than the constant-rate track. On a ramp the track runs ahead of the fan
#: through each blind stretch, and the twin nearer its phase is the wrong one: in spent
#: held-out 3900017 (4 blades, weight 0.96-1.00 down a 0.09 Hz/s reversal) each such
#: match pulled the follower forward, 0.44 Hz read 1.14 Hz within 1.5 s and the
#: reversal came 6.6 s late. Not at even odds: on a steady fan in a glinting room
#: (spent 3800009, 6 blades at 0.35 Hz) a spurious ramp took the weight to 0.51, and
#: twins read its way carried it on to a line the other way (a false reversal pair).
TWIN_FOLLOWER = 0.9
#: The most credit a track holds. A cap rather than a reset on a rejected match: a slow
#: fan's blind half often begins with two clear matches at the mirror angle, which a
#: right track rejects and must still coast through. A cap rather than a long memory of
#: clear matches: a follower whose rate change has the wrong sign must not coast
#: through a reversal on old credit.
COAST_CREDIT = 5
#: Largest innovation a match may have to be taken (blade periods), however wide the gate:
#: after a coast through a slow fan's blind half-period the gate of four standard
#: deviations spans more than the whole circle, and a match half a period off (a mirror
#: angle) is as near the next blade's phase as this one's.
MAX_INNOVATION = 0.25
#: Matches under this quality are the weak ones a track coasts through: with no blade in
#: view every pulse matches one standing phase at 0.01-0.1.
COAST_BELOW = 0.1


@overload
def wrap(d: float) -> float: ...
@overload
def wrap(d: np.ndarray) -> np.ndarray: ...
def wrap(d: float | np.ndarray) -> float | np.ndarray:
    """Wrap a phase difference (cycles) into [-1/2, 1/2)."""
    return (np.asarray(d) + 0.5) % 1.0 - 0.5 if isinstance(d, np.ndarray) else (
        (d + 0.5) % 1.0 - 0.5)


def transition(steps: float, dim: int) -> np.ndarray:
    """State transition over ``steps`` pulses: constant rate (dim 2) or constant rate of
    change (dim 3: phase, rate, acceleration)."""
    n = float(steps)
    if dim == 2:
        return np.array([[1.0, n], [0.0, 1.0]])
    return np.array([[1.0, n, 0.5 * n * n], [0.0, 1.0, n], [0.0, 0.0, 1.0]])


def process_noise(steps: float, dim: int, q: float, q_accel: float = 0.0) -> np.ndarray:
    """Covariance added over ``steps`` pulses by a rate random walk of variance ``q`` per
    pulse and (dim 3) an acceleration random walk of variance ``q_accel`` per pulse
    (continuous white-noise integrals, exact for any gap)."""
    n = float(steps)
    Q = np.zeros((dim, dim))
    Q[:2, :2] = q * np.array([[n ** 3 / 3.0, n * n / 2.0], [n * n / 2.0, n]])
    if dim == 3:
        Q += q_accel * np.array([[n ** 5 / 20.0, n ** 4 / 8.0, n ** 3 / 6.0],
                                 [n ** 4 / 8.0, n ** 3 / 3.0, n * n / 2.0],
                                 [n ** 3 / 6.0, n * n / 2.0, n]])
    return Q


#: A filter's state as plain floats (the tracker's per-pulse path: no numpy array is
#: made at each step): the state vector, and the covariance row by row.
Vec = tuple[float, ...]


def _predict2(x: Vec, P: Vec, q: float, n: float) -> tuple[Vec, Vec]:
    """kalman_predict of the constant-rate model on floats: closed forms."""
    ph, w = x
    p00, p01, _, p11 = P
    a00 = p00 + 2 * n * p01 + n * n * p11 + q * n ** 3 / 3.0
    a01 = p01 + n * p11 + q * n * n / 2.0
    return ((ph + n * w) % 1.0, w), (a00, a01, a01, p11 + q * n)


def _predict3(x: Vec, P: Vec, q: float, n: float, qa: float) -> tuple[Vec, Vec]:
    """kalman_predict of the rate follower's model on floats: F P F^T + Q written out (F =
    transition, Q = process_noise), no matrix products; tests compare it with them."""
    h = 0.5 * n * n
    ph, w, a = x
    p00, p01, p02, _, p11, p12, _, _, p22 = P
    r00, r01, r02 = p00 + n * p01 + h * p02, p01 + n * p11 + h * p12, \
        p02 + n * p12 + h * p22
    r11, r12 = p11 + n * p12, p12 + n * p22
    n2, n3 = n * n, n * n * n
    a00 = r00 + n * r01 + h * r02 + q * n3 / 3.0 + qa * n2 * n3 / 20.0
    a01 = r01 + n * r02 + q * n2 / 2.0 + qa * n2 * n2 / 8.0
    a02 = r02 + qa * n3 / 6.0
    a11 = r11 + n * r12 + q * n + qa * n3 / 3.0
    a12 = r12 + qa * n2 / 2.0
    a22 = p22 + qa * n
    return ((ph + n * w + h * a) % 1.0, w + n * a, a), \
        (a00, a01, a02, a01, a11, a12, a02, a12, a22)


def _innovation(x: Vec, P: Vec, z: float, r: float) -> tuple[float, float]:
    """innovation on floats."""
    return wrap(float(z) - x[0]), P[0] + float(r)


def _mixture(nu: float, s: float, stray: float) -> float:
    """Log likelihood of an innovation ``nu`` (variance ``s``) when a share ``stray`` of
    matches land anywhere in the cycle (density 1): the model comparison's evidence per
    match is bounded, so that where the fingerprint has look-alike angles one match at
    the wrong one cannot swing it."""
    g = math.exp(-0.5 * nu * nu / s) / math.sqrt(2.0 * math.pi * s)
    # (guarded: over hours of clean matches the measured share decays toward zero, and a
    # match far out then has a density that underflows)
    return math.log(max((1.0 - stray) * g + stray, 1e-300))


def _update(x: Vec, P: Vec, z: float, r: float) -> tuple[Vec, Vec]:
    """kalman_update of either model on floats (Joseph form, symmetrised, written out)."""
    nu, s = _innovation(x, P, z, r)
    if not s > 0:
        return x, P
    if len(x) == 2:
        p00, p01, _, p11 = P
        k0, k1 = p00 / s, p01 / s
        a, c = 1.0 - k0, -k1
        n00 = a * a * p00 + k0 * k0 * r
        n01 = a * (c * p00 + p01) + k0 * k1 * r
        n11 = c * c * p00 + 2 * c * p01 + p11 + k1 * k1 * r
        return ((x[0] + k0 * nu) % 1.0, x[1] + k1 * nu), (n00, n01, n01, n11)
    # (I - K H) P (I - K H)^T + K r K^T written out: entry (i, j) is
    # p_ij - k_i p_0j - (p_i0 - k_i p_00) k_j + r k_i k_j, then the off-diagonal pairs
    # averaged (each entry by the same operations as a loop over i, j made them, without
    # the loop's lists: the follower's update is on every pulse's path)
    p00, p01, p02, p10, p11, p12, p20, p21, p22 = P
    k0, k1, k2 = p00 / s, p10 / s, p20 / s
    c0, c1, c2 = p00 - k0 * p00, p10 - k1 * p00, p20 - k2 * p00
    rk0, rk1, rk2 = r * k0, r * k1, r * k2
    m00 = p00 - k0 * p00 - c0 * k0 + rk0 * k0
    m01 = p01 - k0 * p01 - c0 * k1 + rk0 * k1
    m02 = p02 - k0 * p02 - c0 * k2 + rk0 * k2
    m10 = p10 - k1 * p00 - c1 * k0 + rk1 * k0
    m11 = p11 - k1 * p01 - c1 * k1 + rk1 * k1
    m12 = p12 - k1 * p02 - c1 * k2 + rk1 * k2
    m20 = p20 - k2 * p00 - c2 * k0 + rk2 * k0
    m21 = p21 - k2 * p01 - c2 * k1 + rk2 * k1
    m22 = p22 - k2 * p02 - c2 * k2 + rk2 * k2
    m01 = m10 = 0.5 * (m10 + m01)
    m02 = m20 = 0.5 * (m20 + m02)
    m12 = m21 = 0.5 * (m21 + m12)
    return ((x[0] + k0 * nu) % 1.0, x[1] + k1 * nu, x[2] + k2 * nu), \
        (m00, m01, m02, m10, m11, m12, m20, m21, m22)


def _floats(a: np.ndarray) -> Vec:
    """An array's entries as floats, row by row."""
    return tuple(np.asarray(a, dtype=np.float64).ravel().tolist())


def kalman_predict(x: np.ndarray, P: np.ndarray, q: float, steps: int = 1,
                   q_accel: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Propagate ``steps`` pulses (gaps after lost pulses included).

    Parameters
    ----------
    x : ndarray, shape (2,) or (3,)
        [phase (cycles), rate (cycles/pulse)] or with acceleration (cycles/pulse^2).
    P : ndarray, shape like (len(x), len(x))
        Covariance.
    q : float
        Rate noise variance per pulse, (cycles/pulse)^2.
    steps : int
        Pulses to advance.
    q_accel : float
        Acceleration noise variance per pulse (3-state model only).
    """
    dim = len(x)
    if dim in (2, 3):
        # the tracker's and the follower's per-pulse paths (on floats: _predict2/3)
        got = _predict2(_floats(x), _floats(P), q, float(steps)) if dim == 2 else \
            _predict3(_floats(x), _floats(P), q, float(steps), q_accel)
        return np.array(got[0]), np.array(got[1]).reshape(dim, dim)
    F = transition(steps, dim)
    xn = F @ np.asarray(x, dtype=np.float64)
    xn[0] %= 1.0
    Pn = F @ P @ F.T + process_noise(steps, dim, q, q_accel)
    return xn, 0.5 * (Pn + Pn.T)


def innovation(x: np.ndarray, P: np.ndarray, z: float, r: float) -> tuple[float, float]:
    """Wrap-aware innovation ``z - phase`` in [-1/2, 1/2) and its variance ``S``."""
    return float(wrap(float(z) - x.item(0))), P.item(0, 0) + float(r)


def kalman_update(x: np.ndarray, P: np.ndarray, z: float, r: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Measurement update with a phase ``z`` of variance ``r`` (Joseph form, symmetrised)."""
    nu, s = innovation(x, P, z, r)
    if not s > 0:
        return x, P
    if len(x) in (2, 3):
        xf, Pf = _update(_floats(x), _floats(P), z, r)
        return np.array(xf), np.array(Pf).reshape(len(x), len(x))
    K = P[:, 0] / s
    # (I - K H) P (I - K H)^T + K r K^T with H = [1, 0, ...]
    A = np.eye(len(x))
    A[:, 0] -= K
    Pn = A @ P @ A.T + r * np.outer(K, K)
    xn = np.asarray(x, dtype=np.float64) + K * nu
    xn[0] %= 1.0
    return xn, 0.5 * (Pn + Pn.T)


def kalman_step(x: np.ndarray, P: np.ndarray, z: float | None, *, q: float, r: float,
                steps: int = 1, q_accel: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """One pulse: predict ``steps`` pulses, then update with ``z`` (None: predict only).

    Returns
    -------
    x : ndarray, shape (2,)
    P : ndarray, shape (2, 2)
    """
    x, P = kalman_predict(x, P, q, steps, q_accel)
    if z is None:
        return x, P
    return kalman_update(x, P, z, r)


def circular_rate_search(k: np.ndarray, z: np.ndarray, w: np.ndarray, max_rate: float
                         ) -> tuple[float, float, float]:
    """Rate and phase of matches by circular regression (robust to outliers and wraps).

    Parameters
    ----------
    k : ndarray, shape (n,)
        Pulse numbers.
    z : ndarray, shape (n,)
        Matched phases, cycles.
    w : ndarray, shape (n,)
        Weights (match qualities), >= 0.
    max_rate : float
        Search |rate| <= max_rate, cycles per pulse (< 1/2).

    Returns
    -------
    rate : float
        Cycles per pulse.
    phase : float
        Fitted phase at the last pulse ``k[-1]``, cycles.
    coherence : float
        In [0, 1]: 1 when every match lies on the line, about ``1/sqrt(n)`` for noise.
    """
    k = np.asarray(k, dtype=np.float64)
    kk = k - k[-1]
    span = max(float(kk.max() - kk.min()), 1.0)
    sw = float(np.sum(w))
    if not sw > 0:
        return 0.0, 0.0, 0.0
    step = 1.0 / (8.0 * span)
    grid = np.arange(-max_rate, max_rate + step / 2, step)
    u = np.exp(2j * np.pi * np.asarray(z, dtype=np.float64)) * w
    c = np.exp(-2j * np.pi * np.outer(grid, kk)) @ u
    mag = np.abs(c) / sw
    g = int(np.argmax(mag))
    rate = float(grid[g])
    if 0 < g < len(grid) - 1:
        a, b, cc = mag[g - 1], mag[g], mag[g + 1]
        den = a - 2 * b + cc
        if den < 0:
            rate += float(0.5 * (a - cc) / den) * step
    cbest = complex(np.sum(u * np.exp(-2j * np.pi * rate * kk)))
    return rate, (math.atan2(cbest.imag, cbest.real) / (2 * math.pi)) % 1.0, abs(cbest) / sw


def parabola_slope(k: np.ndarray, u: np.ndarray, w: np.ndarray, at: float,
                   scale: float) -> float:
    """The slope at pulse ``at`` (cycles per pulse) of the weighted least-squares parabola
    through unwrapped phases ``u`` at pulses ``k`` (each row weighed by ``w``: a squared
    weight in the sum); ``scale`` (pulses, > 0) only conditions the system. NaN when it is
    singular."""
    x = (np.asarray(k, dtype=np.float64) - at) / scale
    w = np.asarray(w, dtype=np.float64)
    A = np.column_stack([w, w * x, w * x * x])
    c, _, rank, _ = np.linalg.lstsq(A, np.asarray(u, dtype=np.float64) * w, rcond=None)
    return float(c[1]) / scale if rank == 3 else float("nan")


def curved_start(k: np.ndarray, z: np.ndarray, var: np.ndarray, rate: float, phase: float,
                 max_accel: float, *, outlier: float = 0.15
                 ) -> tuple[np.ndarray, np.ndarray] | None:
    """(phase, rate, rate change) at the last pulse ``k[-1]`` from matches ``z`` near the
    line of ``rate`` and ``phase`` (at ``k[-1]``), with their covariance: weighted least
    squares of a parabola on the wrapped residuals, the matches further than ``outlier``
    cycles from the line left out (and, in a second pass, those beyond four of their
    standard deviations from the first curve), and the rate change given a zero-mean
    prior of standard deviation ``max_accel`` (so that a short, noisy stretch cannot claim
    a steep ramp). None when fewer than four matches are left or the system is singular.

    Parameters
    ----------
    k, z, var : ndarray, shape (n,)
        Pulse numbers, matched phases (cycles) and their measurement variances.
    rate, phase : float
        The straight line (cycles per pulse, cycles at ``k[-1]``).
    max_accel : float
        Prior standard deviation of the rate change, cycles per pulse per pulse (> 0).
    """
    k = np.asarray(k, dtype=np.float64)
    var = np.asarray(var, dtype=np.float64)
    dk = k - k[-1]
    X = np.stack([np.ones(len(k)), dk, 0.5 * dk ** 2], axis=1)
    res = np.asarray(wrap(np.asarray(z, dtype=np.float64) - (phase + rate * dk)))
    keep = (np.abs(res) <= outlier) & np.isfinite(res) & (var > 0)
    if not max_accel > 0:
        return None
    got = None
    for _ in range(2):
        # the second pass leaves out what lies beyond four standard deviations of the
        # first curve: wild matches that happened to fall near the line
        if keep.sum() < 4:
            return got
        Xk, w = X[keep], 1.0 / var[keep]
        A = Xk.T @ (Xk * w[:, None])
        A[2, 2] += 1.0 / max_accel ** 2
        try:
            cov = np.linalg.inv(A)
        except np.linalg.LinAlgError:
            return got
        if not np.all(np.isfinite(cov)):
            return got
        theta = cov @ (Xk.T @ (w * res[keep]))
        got = (np.array([(phase + theta[0]) % 1.0, rate + theta[1], theta[2]]),
               0.5 * (cov + cov.T))
        keep &= np.abs(res - X @ theta) <= 4.0 * np.sqrt(np.where(var > 0, var, 0.0))
    return got


#: What :attr:`Tracker.identity` gives: (first pulse of the lock's matches, moves to an
#: alias line, re-checks).
TrackId = tuple[int | None, int, int]


@dataclass(frozen=True)
class TrackerSettings:
    """Tuning of :class:`Tracker` (from config ``tracking``).

    Attributes
    ----------
    max_rate : float
        Slew bound: largest |rate| followed, cycles per pulse (``slew_limit`` times the
        reference rate, and below 1/2).
    q_rate : float
        Rate random-walk variance per pulse, (cycles/pulse)^2.
    meas_sigma : float
        Phase noise of a perfect match (quality 1), cycles; scaled by 1/quality.
    gate_sigma : float
        Innovation gate in standard deviations.
    reacquire_after : int
        Consecutive outliers that trigger a re-initialisation.
    init_pulses : int
        Matches used by the circular-regression initialisation.
    min_coherence : float
        Coherence needed to lock.
    min_info : float
        Quality the best of those matches must reach to lock. With no blade in view no
        match reached 0.14 (a fan at rest at 7 angles in the four simulated rooms, 10 and
        40 dB, 12 s each); a turning fan's best match in any window of 24 pulses reached
        0.29 or more, down to the hardest case, exactly 1/16 blade period per pulse,
        where the pulses see one informative angle every 16 pulses.
    q_accel : float
        Acceleration random-walk variance per pulse, (cycles/pulse^2)^2, of the rate
        follower. Above 0 a second, three-state filter (phase, rate, rate change per
        pulse) runs beside the constant-rate track on the matches the track accepts, so
        that a fan speeding up or slowing down is followed without lag (the match quality
        drops over part of each blade period in many rooms, and a constant-rate model
        coasts through that gap on the old rate); 0: no follower.
    max_accel : float
        Largest |acceleration| the follower starts with as uncertainty (cycles/pulse^2).
    coast_max : int
        Longest coast through weak matches, pulses (:meth:`Tracker._coasts`); 0: none.
    coast_min_rate : float
        A track slower than this (cycles per pulse) does not coast.
    """

    max_rate: float
    q_rate: float = 1e-7
    meas_sigma: float = 0.02
    gate_sigma: float = 4.0
    reacquire_after: int = 6
    init_pulses: int = 24
    min_coherence: float = 0.6
    min_info: float = 0.2
    q_accel: float = 0.0
    max_accel: float = 0.0
    coast_max: int = 0
    coast_min_rate: float = 0.0


@dataclass
class TrackState:
    """The tracker's answer after one pulse."""

    k: int
    z: float
    quality: float
    phase: float
    rate: float
    rate_std: float
    locked: bool
    outlier: bool
    coherence: float


class _FloatState:
    """A Tracker's float state (``_x`` for ``x``) given out as a read-only array, made once
    per state (the array last given out is kept beside it); an array set is stored as
    floats."""

    def __init__(self, dim: int, square: bool, doc: str) -> None:
        self.shape = (dim, dim) if square else (dim,)
        self.__doc__ = doc
        self.name = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = "_" + name

    def __get__(self, obj: Tracker, objtype: type | None = None) -> np.ndarray | None:
        v: Vec | None = getattr(obj, self.name)
        if v is None:
            return None
        got = obj._arrays.get(self.name)
        if got is not None and got[0] is v:
            return got[1]
        a = np.array(v).reshape(self.shape)
        a.flags.writeable = False
        obj._arrays[self.name] = (v, a)
        return a

    def __set__(self, obj: Tracker, value: np.ndarray | None) -> None:
        setattr(obj, self.name, None if value is None else _floats(value))


@dataclass
class Tracker:
    """Per-pulse tracker for the daemon: matches in, (phase, rate) estimates out.

    Feed every pulse with :meth:`update` (pulse number, matched phase, match quality); a
    lost pulse is simply not fed, its gap is propagated by the next update.
    """

    settings: TrackerSettings
    #: the track's state (phase, rate) and covariance (row by row) as floats, None while
    #: unlocked: :attr:`x` and :attr:`P` give them as arrays
    _x: Vec | None = None
    _P: Vec | None = None
    last_k: int | None = None
    outlier_run: int = 0
    outliers: int = 0
    #: clear matches rejected in a row, the faint ones between them passed over: a faint
    #: match (no blade in view) lies in any gate and resets the run of outliers, so that
    #: a track standing still at a blind angle outlived a fan turning at 0.6 Hz whose
    #: every clear match it rejected (spent held-out 800007: a start 27 s late)
    clear_run: int = 0
    clear_k: int | None = None   # pulse of the last clear match the track accepted
    _clear_seen: int | None = None   # pulse of the last clear match, taken or not
    #: the sign of the known direction's rate (cycles per pulse; 0 when none is known),
    #: set by the analysis: while one is, a track standing still is given up when a
    #: blade comes back in view off its line after none was for longer than a coast
    #: (:meth:`_stood_blind`)
    known_way: float = 0.0
    stood_blind: int = 0             # standing tracks so given up
    clear_credit: int = 0        # clear-match credit (COAST_STREAK, COAST_CREDIT)
    coasted: int = 0             # weak matches passed over while coasting (_coasts)
    updates: int = 0
    coherence: float = 0.0
    start_k: int | None = None   # first pulse of the matches the current track began from
    locked_k: int | None = None  # pulse at which the current track locked
    relocks: int = 0             # moves of the track to another line (alias checks)
    #: the rate follower's state (phase, rate, acceleration) and covariance, as floats:
    #: :attr:`fx` and :attr:`fP`
    _fx: Vec | None = None
    _fP: Vec | None = None
    evidence: float = 0.0        # log likelihood ratio follower : track, recent matches
    #: share of the recent clear matches that neither the track nor the follower expects
    #: (a fingerprint with look-alike angles matches some pulses there): the weight the
    #: evidence gives such a match (_mixture), measured on this device's matches
    stray: float = STRAY_START
    rechecks: int = 0            # tracks given up because another line fit the matches
    syncs: int = 0               # times the track took the follower's line (_follower_takes)
    given_up: int = 0            # tracks given up for a rate beyond the bound (limit_rate)
    #: largest |rate| a new line may have (cycles per pulse): the analysis bounds it by
    #: how fast a fan last published at some speed, or at rest, can have sped up since
    #: (analyzer.RateBound)
    rate_bound: float = math.inf
    #: smallest |rate| a new line may have (cycles per pulse): a fan published turning
    #: at some speed cannot have slowed faster than the steepest ramp since
    #: (analyzer.RateBound); 0 when nothing is known
    rate_least: float = 0.0
    _recent: deque[tuple[int, float, float]] = field(default_factory=deque)
    # (weight, accepted) of _recent
    _accepted: deque[tuple[float, bool]] = field(default_factory=deque)
    _followed: bool = False      # the last match was one the reported follower expected
    #: the arrays last given out for the float states (x, P, fx, fP): (state, array)
    _arrays: dict[str, tuple[Vec, np.ndarray]] = field(default_factory=dict, repr=False,
                                                       compare=False)

    def __post_init__(self) -> None:
        self._recent = deque(maxlen=self.settings.init_pulses)
        self._accepted = deque(maxlen=self.settings.init_pulses)

    # The states as arrays (x, P, fx, fP: _FloatState), for readers and for tests that
    # set a state; the per-pulse path works on the floats (a Kalman step made four small
    # arrays at every pulse).
    x = _FloatState(2, False, "The track's state [phase (cycles), rate (cycles per "
                    "pulse)], None unlocked.")
    P = _FloatState(2, True, "The track's covariance, 2x2.")
    fx = _FloatState(3, False, "The follower's state [phase, rate, rate change per "
                     "pulse], None without one.")
    fP = _FloatState(3, True, "The follower's covariance, 3x3.")

    @property
    def follower_phase(self) -> float | None:
        """The follower's phase (cycles), None without a follower."""
        return None if self._fx is None else self._fx[0]

    @property
    def track_rate(self) -> tuple[float, float]:
        """The constant-rate track's (rate, its variance), cycles per pulse; NaN unlocked."""
        if self._x is None or self._P is None:
            return math.nan, math.nan
        return self._x[1], self._P[3]

    @property
    def locked(self) -> bool:
        return self._x is not None

    @property
    def identity(self) -> TrackId:
        """Changes whenever the track starts afresh or is moved to another line."""
        return (self.start_k, self.relocks, self.rechecks)

    @property
    def accel(self) -> tuple[float, float]:
        """The follower's (rate change per pulse, its standard deviation), cycles per
        pulse^2; (0, inf) without a lock or a follower."""
        if self._x is None or self._fx is None:
            return 0.0, math.inf
        assert self._fP is not None   # set with fx
        return self._fx[2], math.sqrt(max(self._fP[8], 0.0))

    @property
    def follower_weight(self) -> float:
        """How much the recent matches favour the follower over the constant-rate track
        (0..1, a posterior model probability with forgetting)."""
        if self._fx is None:
            return 0.0
        e = max(min(self.evidence, 50.0), -50.0)
        return 1.0 / (1.0 + math.exp(-e))

    @property
    def rate(self) -> tuple[float, float]:
        """The rate to report and its standard deviation (cycles per pulse): the
        follower's while the recent matches favour it (weight above 1/2: the rate is
        changing, and the follower coasts through the blind part of a blade period on the
        rate's change), else the quieter constant-rate track's (a steady fan: a blend
        made its rate wander by 1.6 % at the 95th percentile, the track's 0.7 %)."""
        if self._x is None:
            return float("nan"), float("nan")
        if self.follower_weight > 0.5:
            assert self._fx is not None and self._fP is not None   # a weight needs a follower
            return self._fx[1], math.sqrt(max(self._fP[4], 0.0))
        assert self._P is not None   # set with x
        return self._x[1], math.sqrt(max(self._P[3], 0.0))

    @property
    def rate_now(self) -> tuple[float, float]:
        """The latest rate and its standard deviation (cycles per pulse): the follower's,
        which follows a change of speed without the constant-rate model's lag (the
        track's without a follower)."""
        if self._x is None:
            return float("nan"), float("nan")
        if self._fx is None or self._fP is None:
            assert self._P is not None
            return self._x[1], math.sqrt(max(self._P[3], 0.0))
        return self._fx[1], math.sqrt(max(self._fP[4], 0.0))

    def limit_rate(self, bound: float) -> bool:
        """Set :attr:`rate_bound` (cycles per pulse) and give up a track faster than it by
        more than twice its rate's standard deviation; True if it was given up. The bound
        limits new lines; a line locked while the bound was higher would otherwise live
        on the weak matches of a fan at rest and claim the next start for its own
        direction."""
        self.rate_bound = bound
        if self._x is None or self._P is None or not math.isfinite(bound):
            return False
        if abs(self._x[1]) - 2.0 * math.sqrt(max(self._P[3], 0.0)) <= bound:
            return False
        self._x = self._P = self._fx = self._fP = None
        self.outlier_run = 0
        self.clear_run = 0
        self.given_up += 1
        return True

    def expect_change(self) -> None:
        """A fan at rest may start at any moment at up to the steepest ramp: the
        follower's rate change is kept that uncertain. At rest its variance would shrink
        to nothing, and the follower would then take up a start over seconds, its rate
        lagging the fan's."""
        if self._fP is not None and self.settings.max_accel > 0:
            v = self.settings.max_accel ** 2
            if self._fP[8] < v:
                self._fP = (*self._fP[:8], v)

    def _limit_accel(self) -> None:
        """No fan changes speed faster than ACCEL_LIMIT times the steepest ramp: the
        follower's rate change is held within it (the estimate projected onto the
        bound, its variance kept), so that a lock taken on the curve of a spin-up cannot
        start it far steeper than any fan ramps."""
        if self._fx is None or not self.settings.max_accel > 0:
            return
        lim = ACCEL_LIMIT * self.settings.max_accel
        if abs(self._fx[2]) > lim:
            self._fx = (self._fx[0], self._fx[1], math.copysign(lim, self._fx[2]))

    def _coasts(self, k: int, quality: float) -> bool:
        """Whether a weak match (under ``COAST_BELOW``) at pulse ``k`` is passed over rather
        than measured. While no blade is in view (the blind part of each blade period in
        many rooms, half of it in the paper room) every pulse matches one standing phase
        at a quality of a few hundredths: fed to the filters, such matches pull the
        follower's rate down as if the fan were slowing, and a run of them off the line
        gives a right track up in the middle of a slow fan's turn. A track that holds
        ``COAST_STREAK`` of clear-match credit (clear matches accepted less those
        rejected, at most ``COAST_CREDIT``) coasts on its prediction instead, for up
        to ``COAST_SHARE`` of its own blade period after the last clear one
        (``coast_max`` pulses at most). Beyond that weak matches are measured and
        counted as outliers, so that a fan stopped with no blade in view is not hidden
        by a coasting track (docs/dynamics.md)."""
        st = self.settings
        if quality >= COAST_BELOW or st.coast_max <= 0 or not self._shown_line():
            return False
        assert self._x is not None
        period = 1.0 / max(abs(self._x[1]), 1e-9)
        return self.clear_k is not None and \
            k - self.clear_k <= min(COAST_SHARE * period, st.coast_max)

    def _stood_blind(self, k: int, z: float) -> bool:
        """Whether a clear match at pulse ``k`` (phase ``z``) ends a stretch of more than
        ``coast_max`` pulses without one, on a track standing still (slower than
        ``coast_min_rate``) while a direction is known (``known_way``). Such a track has
        followed only the weak matches of no blade in view, and where a fan comes back
        after passing zero out of sight, the clear matches that pass its phase drag it
        either way; given up with its matches, the next lock fits the fresh ones alone.
        Kept where it has followed the fan through zero: on the other side of zero from
        the known direction, the match on its line (``MAX_INNOVATION``). Not after a
        confirmed stop (no ``known_way``): there it takes a start's spin-up up at once.
        docs/dynamics.md, "Slow reversals". Notes ``k`` as the last clear match."""
        last, self._clear_seen = self._clear_seen, k
        st = self.settings
        if last is None or self._x is None or st.coast_max <= 0 or self.known_way == 0.0 \
                or not abs(self._x[1]) < st.coast_min_rate or k - last <= st.coast_max:
            return False
        assert self.last_k is not None   # set with x
        return self._x[1] * self.known_way >= 0.0 \
            or abs(wrap(z - self._x[0] - self._x[1] * (k - self.last_k))) > MAX_INNOVATION

    def _shown_line(self) -> bool:
        """Whether the track has shown its line and turns: ``COAST_STREAK`` of clear-match
        credit, and a rate of ``coast_min_rate`` or more. Such a track may coast through
        weak matches and take a match's twin. A track slower than the floor claims no
        direction, and near rest a blade standing at a blind angle is the stop a coast
        must not hide; a follower coasting there would carry a spin-down's deceleration
        through zero, to a line the other way."""
        return self._x is not None and self.clear_credit >= COAST_STREAK \
            and abs(self._x[1]) >= self.settings.coast_min_rate

    def _keep_follower_on_side(self) -> None:
        """A coast carries no match: a follower whose rate has crossed zero against the
        track's is held at rest (rate and rate change zero) rather than carried on by its
        rate change alone, and reported it claims no direction: with no match to correct
        it, a wrong-signed rate change (a lock on a fan starting from rest) would carry
        the follower ever faster the wrong way. Not restarted from the track's line: at
        the zero of a slow reversal the track's rate is the old direction's, seconds
        stale, and reported it would renew the old direction and cut the wait for the
        reversal short (a reversal read as a stop and a start)."""
        if self._fx is not None and self._x is not None \
                and self._fx[1] * self._x[1] < 0.0:
            self._fx = (self._fx[0], 0.0, 0.0)

    def _rejects(self, nu: float, s: float, slew: float) -> bool:
        """Whether an innovation ``nu`` (variance ``s``) lies outside the gate, or further
        than the fastest line could move (``slew``, cycles), or further than
        ``MAX_INNOVATION`` whatever the gate."""
        return nu * nu > self.settings.gate_sigma ** 2 * s or abs(nu) > max(slew, 0.05) \
            or abs(nu) > MAX_INNOVATION

    def _follower_takes(self, f: tuple[float, float] | None) -> bool:
        """Whether a match the track rejects is one the follower, clearly favoured by the
        recent matches (weight over SYNC_WEIGHT), expects (within the gate); ``f``: the
        follower's innovation of the match and its variance (None without a follower)."""
        if f is None or self.follower_weight <= SYNC_WEIGHT:
            return False
        fnu, fs = f
        return fnu * fnu <= self.settings.gate_sigma ** 2 * fs

    def _follower_expects(self, f: tuple[float, float] | None, slew: float) -> bool | None:
        """Whether the follower, while its rate is the one reported (weight over 1/2,
        :attr:`rate`), expects a match (``f``, as for :meth:`_follower_takes`: within
        its own gate); None while it is not reported. A match it refuses is not taken,
        whatever the lagging constant-rate track says: the track's wider gate can hold a
        clear match at the mirror angle (at the edge of a slow fan's blind half-period),
        which folded into the follower would throw its rate far off."""
        if f is None or self.follower_weight <= 0.5:
            return None
        return not self._rejects(f[0], f[1], slew)

    def _follow_from_track(self) -> None:
        """(Re)start the follower on the track's line, its acceleration unknown up to the
        steepest ramp."""
        st = self.settings
        if st.q_accel <= 0 or self._x is None:
            self._fx = self._fP = None
            return
        assert self._P is not None   # set with x
        self._fx = (self._x[0], self._x[1], 0.0)
        p00, p01, p10, p11 = self._P
        self._fP = (p00, p01, 0.0, p10, p11, 0.0, 0.0, 0.0, st.max_accel ** 2)
        self.evidence = 0.0

    def _follow_from_matches(self) -> None:
        """Start the follower from a curved line through the matches of the lock (phase,
        rate and rate change at the last one): a lock taken on a ramp (a spin-up, the far
        side of a reversal) has a straight line's rate from the middle of its matches,
        up to half their span behind, and the follower would start there with no change.
        The change has the steepest ramp as its prior (:func:`curved_start`)."""
        st = self.settings
        if self._fx is None or self._x is None or len(self._recent) < 4:
            return
        k, z, q = (np.array(v, dtype=np.float64) for v in zip(*self._recent, strict=True))
        var = np.array([self.r(qq) for qq in q])
        got = curved_start(k, z, var, self._x[1], self._x[0], st.max_accel)
        if got is None:
            return
        self.fx, self.fP = got
        self._limit_accel()

    def r(self, quality: float) -> float:
        """Measurement variance of a match of this quality."""
        s = self.settings.meas_sigma / max(float(quality), 0.05)
        return min(s, 0.5) ** 2

    def _fit(self) -> tuple[np.ndarray, float, float, float]:
        """Circular regression of the recent matches: (pulses, rate, phase, coherence).

        The coherence is the lower of the quality-weighted one and that of the same line
        with the squared qualities as weights, which the few clear matches dominate:
        when a window holds a few clear matches and many weak ones wandering about (a
        fan just come to rest), a line through the weak ones that misses the clear ones
        is not coherent."""
        k, z, w = (np.array(v) for v in zip(*self._recent, strict=True))
        rate, phase, coh = circular_rate_search(k, z, w, self.max_rate)
        w2 = w * w
        if float(w2.sum()) > 0:
            u = np.exp(2j * np.pi * (z - phase - rate * (k - k[-1])))
            coh = min(coh, float(abs(np.sum(w2 * u)) / w2.sum()))
        return k, rate, phase, coh

    @property
    def max_rate(self) -> float:
        """The largest |rate| a line may have now: the slew bound, or the analysis's
        physical bound when it is lower."""
        return min(self.settings.max_rate, self.rate_bound)

    def _informative(self) -> bool:
        """Whether the recent matches can single out a line: one of them at least has a
        quality of ``min_info``. Coherence alone cannot tell: while no blade is in view
        (a fan at rest at a blind angle, the blind half of each blade period of a slow
        one) every pulse matches one phase of the table at a quality of 0.01-0.1, a
        perfectly coherent line that stands still, and a lock on it would hide a
        spin-up until the line is given up."""
        return max((q for _, _, q in self._recent), default=0.0) >= self.settings.min_info

    def _init(self) -> bool:
        if len(self._recent) < self.settings.init_pulses or not self._informative():
            return False
        k, rate, phase, coh = self._fit()
        self.coherence = coh
        if coh < self.settings.min_coherence or abs(rate) < self.rate_least:
            return False
        self._lock(k, rate, phase, coh)
        return True

    def _lock(self, k: np.ndarray, rate: float, phase: float, coh: float) -> None:
        """Start a track on the fitted line of the matches at pulses ``k``."""
        # wrapped-normal spread of the matches about the line -> initial covariance
        var = min(max(-2.0 * math.log(max(coh, 1e-9)) / (2 * math.pi) ** 2, 1e-8), 0.1)
        n = float(len(k))
        span = max(float(k[-1] - k[0]), 1.0)
        self._x = (float(phase), float(rate))
        self._P = (4.0 * var / n, 0.0, 0.0, 12.0 * var / (n * span * span))
        self.last_k = int(k[-1])
        self.start_k = int(k[0])
        self.locked_k = int(k[-1])
        self.outlier_run = 0
        self.clear_run = 0
        self.clear_k = max((kk for kk, _, q in self._recent if q >= self.settings.min_info),
                           default=None)
        self.clear_credit = 0
        self._accepted.clear()
        self._follow_from_track()
        self._follow_from_matches()

    def recheck(self, aliases: np.ndarray | None = None) -> bool:
        """Give up a track that the recent good matches mostly reject when another line
        fits them well (a lock taken in the middle of a spin-up can settle on a wrong
        line whose few accepted matches keep it alive for seconds); True if it moved.
        ``aliases``: for a rate near p/q cycles per pulse, the lines that fit the matches
        about alike (:func:`aliasing.alias_rates`); a best fit on one of them is left to
        the alias check, which weighs them on the whole window."""
        st = self.settings
        if self._x is None or len(self._accepted) < st.init_pulses or not self._informative():
            return False
        wsum = sum(w for w, _ in self._accepted)
        if not wsum > 1e-12 or sum(w for w, a in self._accepted if a) >= 0.5 * wsum:
            return False
        # the rejected share must rest on several clear matches: among a slow fan's few
        # clear matches in a window, one wild match of high quality alone can make the
        # share large and its line replace a right track
        clear = st.min_info ** 2
        if sum(1 for w, a in self._accepted if not a and w >= clear) < RECHECK_REJECTED:
            return False
        k, rate, phase, coh = self._fit()
        span = max(float(k[-1] - k[0]), 1.0)
        if coh < st.min_coherence or abs(rate - self._x[1]) <= 1.0 / span \
                or abs(rate) < self.rate_least:
            return False
        if aliases is not None and len(aliases) and \
                float(np.min(np.abs(np.asarray(aliases) - rate))) <= 1.0 / span:
            return False
        self.coherence = coh
        self._lock(k, rate, phase, coh)
        self.rechecks += 1
        return True

    def let_go(self) -> None:
        """Give up the track: the next match starts a lock fitted on the recent ones (as
        after ``reacquire_after`` outliers)."""
        self._x = self._fx = self._fP = None

    def forget_matches(self) -> None:
        """Drop the matches kept for a (re)lock and a re-check: after a gap of unknown
        length they would join both sides of a hidden jump in one line."""
        self._recent.clear()
        self._accepted.clear()

    def relock(self, rate: float, phase: float, k: int) -> None:
        """Move a locked track to another line (rate, phase at pulse ``k``), keeping its
        covariance: an alias check found the line the matches alone could not single out."""
        if self._x is None:
            return
        self._x = (float(phase) % 1.0, float(rate))
        self._accepted.clear()
        self._follow_from_track()
        self.last_k = int(k)
        self.relocks += 1
        self.outlier_run = 0
        self.clear_run = 0

    def update(self, k: int, z: float, quality: float, twin: float = math.nan
               ) -> TrackState:
        """Fold in pulse ``k`` matched at phase ``z`` (cycles) with quality in [0, 1].
        ``twin``: the angle whose pulses also match there (:func:`fingerprint.twin_bins`;
        NaN: none): a turning track that has shown its line (:meth:`_shown_line`, as
        for a coast) measures whichever of the two its line expects (the follower's
        from ``TWIN_FOLLOWER`` on: on a ramp the constant-rate line runs ahead). Not
        otherwise: a twin is a second chance for any line, and in spent held-out scene
        1500001 a fresh wrong one (half the rate, the other way, in a reversal's
        spin-up) was kept by them for half a minute, and a line standing at rest for
        110 s after the fan started."""
        st = self.settings
        if quality >= st.min_info and self._stood_blind(int(k), float(z)):
            self.let_go()
            self.forget_matches()
            self.stood_blind += 1
        self._recent.append((int(k), float(z), max(float(quality), 0.0)))
        outlier = False
        if self._x is None:
            self._init()
        else:
            assert self._P is not None and self.last_k is not None   # set with x
            steps = float(max(int(k) - int(self.last_k), 1))
            self._x, self._P = _predict2(self._x, self._P, st.q_rate, steps)
            if self._fx is not None:
                assert self._fP is not None   # set with fx
                self._fx, self._fP = _predict3(self._fx, self._fP, st.q_rate, steps,
                                               st.q_accel)
            self.last_k = int(k)
            if self._coasts(int(k), quality):
                self.coasted += 1
                self._keep_follower_on_side()
            else:
                if twin == twin and self._shown_line():
                    # (NaN: no twin) whichever of the two the line expects: the
                    # follower's once the matches clearly favour it (TWIN_FOLLOWER)
                    at = self._fx[0] if self._fx is not None \
                        and self.follower_weight >= TWIN_FOLLOWER else self._x[0]
                    if abs(wrap(twin - at)) < abs(wrap(z - at)):
                        z = twin
                outlier = self._measure(int(k), z, quality)
        if self._x is not None:
            w = max(float(quality), 0.0)
            self._accepted.append((w * w, not outlier or self._followed))
            self._followed = False
        if self._x is None:
            return TrackState(int(k), float(z), float(quality), float("nan"), float("nan"),
                              float("nan"), False, outlier, self.coherence)
        assert self._P is not None   # set with x
        return TrackState(int(k), float(z), float(quality), self._x[0], self._x[1],
                          math.sqrt(max(self._P[3], 0.0)), True, outlier,
                          self.coherence)

    def _measure(self, k: int, z: float, quality: float) -> bool:
        """Gate and fold in one match on a track predicted to its pulse; True if it was
        an outlier."""
        st = self.settings
        assert self._x is not None and self._P is not None   # a locked track
        clear = quality >= st.min_info
        r = self.r(quality)
        nu, s = _innovation(self._x, self._P, z, r)
        slew = st.max_rate + 3.0 * math.sqrt(max(self._P[3], 0.0))
        # the follower's innovation, once: a sync below changes the track, not the follower
        f = _innovation(self._fx, self._fP, z, r) \
            if self._fx is not None and self._fP is not None else None
        expected = self._follower_expects(f, slew)
        refused = expected is False
        # a match the reported follower expects is no sign against the track's line
        # (Tracker.recheck) even when the lagging track rejects it
        self._followed = bool(expected)
        rejected = self._rejects(nu, s, slew)
        if clear:
            stray = rejected and (f is None or self._rejects(*f, slew))
            self.stray += (float(stray) - self.stray) / STRAY_MEMORY
        if not refused and rejected and self._follower_takes(f):
            # the constant-rate track lags a ramp the follower is on: it takes the
            # follower's line instead of counting the match out (a run of such outliers
            # would give the track, and the follower with it, up in mid-ramp)
            assert self._fx is not None and self._fP is not None
            self._x = (self._fx[0], self._fx[1])
            f00, f01, _, f10, f11 = self._fP[:5]
            f01 = 0.5 * (f01 + f10)    # (symmetrised; the diagonal is its own mirror)
            self._P = (f00, f01, f01, f11)
            self.syncs += 1
            nu, s = _innovation(self._x, self._P, z, r)
            rejected = self._rejects(nu, s, slew)
        if refused or rejected:
            self.outliers += 1
            self.outlier_run += 1
            if clear:
                self.clear_credit = max(self.clear_credit - 1, 0)
                self.clear_run += 1
            if self.outlier_run >= st.reacquire_after or self.clear_run >= st.reacquire_after:
                self.let_go()
                self._init()
            return True
        if self._fx is not None and f is not None:
            assert self._fP is not None   # set with fx
            fnu, fs = f
            ll = _mixture(fnu, fs, self.stray) - _mixture(nu, s, self.stray)
            self.evidence += ll - self.evidence / FOLLOW_MEMORY
            self._fx, self._fP = _update(self._fx, self._fP, z, r)
            self._limit_accel()
        self._x, self._P = _update(self._x, self._P, z, r)
        self.outlier_run = 0
        self.updates += 1
        if clear:
            self.clear_run = 0
            self.clear_k = k
            self.clear_credit = min(self.clear_credit + 1, COAST_CREDIT)
        return False
