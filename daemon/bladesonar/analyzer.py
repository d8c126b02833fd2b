"""The streaming analyzer (pure, no I/O): aligned pulses in, matches, a track, motion
evidence and decisions out, pulse by pulse as the daemon runs it and block by block as
``analyze`` (offline.py) runs it.

align -> remove the running static part -> envelope features -> match -> Kalman track
(checked against its aliases when the rate is near p/q blade period per pulse) -> motion
evidence -> decision -> state machine (transitions.py).

Per pulse, analysis costs an alignment of the gated window, one envelope (FFT of the gate),
one row of a matrix product against the table, a 2x2 Kalman step and ``max_lag`` vector
differences. The tuning constants are in tuning.py, the reference in reference_build.py.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .answer import WAY_KINDS, WAYS, Decision, Direction, Kind, RateState
from .config import Config
from .dsp import aliasing, rangescale
from .dsp import device as dev
from .dsp import fingerprint as fp
from .dsp.decide import (
    AcceptFloor,
    MotionMeter,
    NoiseFloor,
    RestFloor,
    TurningFloor,
    decide,
    noise_threshold,
)
from .dsp.pulses import DROPOUT, OK, WARMUP, AlignedPulses, PulseAligner
from .dsp.stats import median
from .dsp.tracking import MAX_INNOVATION, Tracker, TrackState, parabola_slope, wrap
from .reference_build import Reference, check_compatible
from .transitions import Event, Transitions
from .tuning import (
    ACCEPT_CLEAR_SD,
    ACCEPT_KEEP,
    ACCEPT_LEAST,
    ACCEPT_LEAST_SHARE,
    ANCHOR_TRUST_S,
    HOLD_S,
    NOISE_FALL,
    NOISE_MARGIN,
    RAMP_FIT_LEAST,
    RAMP_FIT_S,
    RECHECK_EVERY,
    REST_KEEP,
    REST_LEAST,
    REST_SHIFT_MAX,
    SCALE_EVERY,
    SCALE_LIMIT,
    SCALE_MIN_CORR,
    SETTLED_AGREE,
    SLOW_FACTOR,
    SNAPSHOT_EVERY,
    SNAPSHOTS,
    START_STILL,
    STILL_BAND,
    STILL_WINDOW_S,
    TREND_SHARE,
    TURNING_QUANTILE,
    UNTRUSTED_FACTOR,
    decide_settings,
    tracker_settings,
    transition_settings,
)


def new_aligner(cfg: Config, ref: Reference) -> PulseAligner:
    """The aligner for analysing against ``ref``: its gate, and the pulses a pulse train's
    start needs before the room's reverberation has built up (measured in the reference)
    marked as warm-up."""
    warm = int(ref.meta.get("warmup_pulses", 0) or 0)
    return PulseAligner(cfg.waveform.pri_samples, ref.gate, warmup=max(1, warm + 1))


def _keep_norm(v: np.ndarray, norm2: float) -> None:
    """Scale ``v`` in place back to the square norm ``norm2`` it had before a step."""
    n2 = float(v @ v)
    if n2 > 0:
        v *= math.sqrt(norm2 / n2)


def low_band_norms(x: np.ndarray) -> np.ndarray:
    """Norms of pulses ``x`` (n, L) through [1, 2, 1] / 4 along range, which is nought at
    the Nyquist frequency: under clock drift the top of the band of a strong, sharp
    echo changes with the sub-sample position (the fractional shift is least exact
    there), by a fifth of its energy at 40 ppm, and the plain norm with it."""
    y = x[:, :-2] + 2.0 * x[:, 1:-1] + x[:, 2:]
    out: np.ndarray = np.sqrt(np.einsum("ij,ij->i", y, y)) / 4.0
    return out


def at_one_level(x: np.ndarray, level: float) -> np.ndarray:
    """Pulses ``x`` (n, L) each scaled so that its :func:`low_band_norms` is ``level`` (a
    pulse with none stays as it is).

    Why: under ``normalise`` the pulses come scaled against the static estimate by
    least squares. That scale moves when the estimate does: when the fan comes to rest
    the estimate moves over seconds to the resting room (a resting blade's glint can
    double a pulse's projection on it), and under drift the projection follows the
    sub-sample position. The short meter, which calls rest when the pulses stop
    changing, read both as motion (stops 8.4 and 4.8 s late, held-out 3700008, a loud
    fan at 29.5 dB). At one level a resting pulse keeps its scale, and a device gain
    (an AGC) still cancels."""
    n = low_band_norms(x)
    ok = n > 0
    return x * np.where(ok, level / np.where(ok, n, 1.0), 1.0)[:, None]


class StaticRemover:
    """Running mean pulse (the static room) subtracted from each pulse, state in and out.

    An exponential average with time constant ``window`` pulses; each pulse is compared
    with the average of the pulses *before* it. ``prime`` starts the average from a block
    of pulses (the daemon's warm-up; offline, the first window of the recording).
    """

    #: (``normalise``) the gain reference of the pulses handed on, from RestHold's first
    #: hold on: the estimate as it stood, adapting on, whatever the held estimate is.
    #: None: the estimate itself
    gain_ref: np.ndarray | None = None
    #: hold the estimate, the fan still turning (a slow fan: see RestHold); unlike
    #: ``frozen`` it says nothing of rest
    held: bool = False

    def __init__(self, alpha: float, mean: np.ndarray) -> None:
        self.alpha = float(alpha)
        self.mean = np.asarray(mean, dtype=np.float64).copy()
        # the pulses' gain against the static estimate, smoothed over a third of its
        # window, and the range it has covered (the device figure gain_wander_db)
        self._gain = math.nan
        self._gain_n = 0
        #: scale each pulse to the static estimate's gain (set where the reference saw the
        #: device's gain wander: an AGC; elsewhere it would only add the fan's share of
        #: the projection as jitter on the strong static echoes)
        self.normalise = False
        #: hold the estimate (a fan at rest: see RestHold)
        self.frozen = False
        #: (pulse, estimate after it) every SNAPSHOT_EVERY pulses, the last SNAPSHOTS
        self.history: deque[tuple[int, np.ndarray]] = deque(maxlen=SNAPSHOTS)
        self._next_copy = -(10 ** 18)
        self.gain_lo = math.inf
        self.gain_hi = 0.0

    def copy(self) -> StaticRemover:
        """An independent copy (a block's rewind point): the estimate is copied, the
        snapshots are shared (they are never written; a deep copy of them was a tenth of
        the daemon's CPU per block)."""
        c = copy.copy(self)
        c.mean = self.mean.copy()
        c.gain_ref = None if self.gain_ref is None else self.gain_ref.copy()
        c.history = deque(self.history, maxlen=self.history.maxlen)
        return c

    @property
    def gain_wander_db(self) -> float:
        """Peak-to-peak wander of the smoothed gain seen so far, dB (0 before it settles)."""
        if not self.gain_hi > 0 or not math.isfinite(self.gain_lo):
            return 0.0
        return 20.0 * math.log10(self.gain_hi / self.gain_lo)

    def _note_gain(self, g: float) -> None:
        b = min(3.0 * self.alpha, 1.0)
        self._gain = g if not math.isfinite(self._gain) else self._gain + b * (g - self._gain)
        self._gain_n += 1
        if self._gain_n * b >= 1.0:
            self.gain_lo = min(self.gain_lo, self._gain)
            self.gain_hi = max(self.gain_hi, self._gain)

    def __call__(self, pulses: np.ndarray) -> np.ndarray:
        """Residuals of a block of consecutive pulses, shape (n, L); updates the state."""
        x = np.asarray(pulses, dtype=np.float64)
        if len(x) == 0:
            return x.copy()
        # mean <- mean + alpha (x - mean), pulse by pulse. A plain loop rather than
        # scipy.signal.lfilter: importing scipy.signal costs the daemon 75 MiB of RSS and a
        # second of start-up for this one first-order recursion (2 vector ops per pulse).
        a, mean = self.alpha, self.mean
        res = np.empty_like(x)
        for i in range(len(x)):
            np.subtract(x[i], mean, out=res[i])
            mean += a * res[i]
        return res

    def skip_bursts(self, pulses: np.ndarray, gate: dev.BurstGate,
                    index: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Like calling the remover, but each pulse is first scaled to the static
        estimate's gain (least squares), and a pulse the burst gate flags (its residual's
        median square far above the recent pulses') is not averaged into the static
        estimate. Returns (scaled pulses, residuals, burst mask). With the pulses'
        numbers ``index``, a copy of the estimate is kept every SNAPSHOT_EVERY pulses
        (``history``: the same pulses whatever the blocks)."""
        x = np.array(pulses, dtype=np.float64)
        if not self.normalise and len(x) > 1:
            got = self._unburst_block(x, gate, index)
            if got is not None:
                return got
        a, mean = self.alpha, self.mean
        res = np.empty_like(x)
        burst = np.zeros(len(x), bool)
        ref = self.gain_ref if self.normalise else None
        out = x if ref is None else x.copy()
        rr = gr = 0.0
        for i in range(len(x)):
            if ref is not None:
                # the pulse handed on (the short meter's, the noise level's) at its gain
                # against an estimate that is never swapped: a held estimate from while
                # the fan turned put every resting pulse at another gain (1.24 times for
                # a loud fan) and the short meter took that step for motion for a whole
                # window
                rr = float(ref @ ref)
                gr = float(x[i] @ ref) / rr if rr > 0 else 1.0
                if gr > 0:
                    out[i] /= gr
            # brought to the static estimate's gain first (an AGC's slow wander), as the
            # reference's pulses were
            mm = float(mean @ mean)
            g = float(x[i] @ mean) / mm if mm > 0 else 1.0
            if g > 0 and self.normalise:
                x[i] /= g
            np.subtract(x[i], mean, out=res[i])
            # the burst level: the median square of every 4th sample (a burst covers the
            # window, the fan's echoes are a few samples); a partition, not a sort
            r4 = res[i, ::4]
            sq = r4 * r4
            h = len(sq) // 2
            if gate(float(np.partition(sq, h)[h])):
                burst[i] = True
                continue
            if g > 0:
                self._note_gain(g)
            if ref is not None and gr > 0 and rr > 0:
                # (adapting as the estimate does, held or not, and its norm kept likewise)
                ref += a * (out[i] - ref)
                _keep_norm(ref, rr)
            if not (self.frozen or self.held):
                mean += a * res[i]
                if g > 0 and self.normalise and mm > 0:
                    # a scaled pulse's residual is orthogonal to the estimate (least
                    # squares), so each step adds a^2 |r|^2 to its square norm and the
                    # estimate, the scale every pulse is brought to, grew without end:
                    # x2000 in 20 000 pulses of a loud fan near the sensor, until no
                    # pulse matched the reference table. Its norm stays where it was.
                    _keep_norm(mean, mm)
            if index is not None and int(index[i]) >= self._next_copy:
                self.history.append((int(index[i]), mean.copy()))
                self._next_copy = int(index[i]) + SNAPSHOT_EVERY
        return out, res, burst

    def _unburst_block(self, x: np.ndarray, gate: dev.BurstGate, index: np.ndarray | None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """skip_bursts on a block with no burst in it, unscaled (``normalise`` off): the
        recursion alone runs pulse by pulse (the same operations, the same estimate
        and residuals), the burst levels and the gains are taken for the whole block
        afterwards (the gains' dot products summed in another order: the gain figures
        may move in their last bits). None, with nothing changed, when a pulse of the
        block is a burst: skip_bursts then runs pulse by pulse."""
        a, n = self.alpha, len(x)
        before = (self.history.copy(), self._next_copy)
        saved_gate = gate.copy()
        res = np.empty_like(x)
        # the estimate before each pulse, 32 pulses at a time (row j + 1 after pulse j),
        # and the dot products the gains need, taken for those pulses together
        means = np.empty((33, x.shape[1]))
        means[0] = self.mean
        step = np.empty(x.shape[1])
        keep = [] if index is None else index.tolist()
        mm, xm = np.empty(n), np.empty(n)
        for c0 in range(0, n, 32):
            c1 = min(c0 + 32, n)
            for i in range(c0, c1):
                j = i - c0
                np.subtract(x[i], means[j], out=res[i])
                if self.frozen or self.held:
                    means[j + 1] = means[j]
                else:
                    np.multiply(res[i], a, out=step)        # mean += a * res, as above
                    np.add(means[j], step, out=means[j + 1])
                if keep and keep[i] >= self._next_copy:
                    self.history.append((keep[i], means[j + 1].copy()))
                    self._next_copy = keep[i] + SNAPSHOT_EVERY
            m = means[:c1 - c0]
            mm[c0:c1] = np.einsum("ij,ij->i", m, m)
            xm[c0:c1] = np.einsum("ij,ij->i", x[c0:c1], m)
            means[0] = means[c1 - c0]
        sq = res[:, ::4] * res[:, ::4]
        h = sq.shape[1] // 2
        levels = np.partition(sq, h, axis=1)[:, h].tolist()
        for lv in levels:
            if gate(lv):
                # a burst: everything back as it was, and the pulse-by-pulse loop
                self.history, self._next_copy = before
                gate.__dict__.update(saved_gate.__dict__)
                return None
        self.mean[:] = means[0]
        for m2, xmi in zip(mm.tolist(), xm.tolist(), strict=True):
            g = xmi / m2 if m2 > 0 else 1.0
            if g > 0:
                self._note_gain(g)
        return x, res, np.zeros(n, bool)


def _rows_of(block: AlignedPulses, keep: np.ndarray) -> AlignedPulses:
    """The pulses of ``block`` where ``keep`` is true."""
    return AlignedPulses(block.pulses[keep], block.edges[keep], block.index[keep],
                         block.status[keep])


class RestHold:
    """While the fan rests, the static estimate is the room as it was while the fan
    turned (its echo averaged over angles), held. Left to adapt it takes in the echo of
    the blade at rest, and that adapting itself reads as motion, and when the fan starts
    the rest echo stays in every residual as a ghost at the rest angle. Held, a resting
    blade leaves the residual a turning one leaves at that angle, and the track follows
    it from rest when the fan starts (docs/dynamics.md, "Why each rule is there").

    Held from the first 'stopped' decision after the fan was seen turning at
    ``turning_hz`` (three times the floor) or more (the copy of the estimate from then)
    until it is seen turning at that rate again, either way or with its direction in
    doubt (a weak answer in the old direction from a spurious line near rest does not
    count), but no longer than ``max_pulses`` (HOLD_S): over a long rest the room itself
    drifts, and an old estimate would leave that drift in every residual.

    A fan seen turning slower than ``turning_hz`` after it was seen at that rate (the
    end of a spin-down, a reversal through zero) lingers near one angle for seconds, and
    the estimate takes in its echo the same way: after the zero of a slow reversal the
    ghost held the track at rest while the fan sped up the other way, for 2-3 s. So the
    estimate also stops adapting from the first decision that reads the fan under
    ``turning_hz`` (``StaticRemover.held``, which, unlike a rest's hold, tells the
    analysis nothing of rest), and adapts again on the same release, or after
    ``slow_pulses`` (a rest that follows is still held: a spin-down from 0.2 Hz is that
    slow for longer): the longest a fan driven through zero stays under ``turning_hz``
    (down and up again at ``min_spinup_hz_s``, 6 s): the ghost is a reversal's, and a
    fan that stays slow, or a fast one whose decisions read a slow line where its
    track keeps losing it, should not keep an estimate that no longer follows the room
    (the aligner's error under drift, a device's gain) for up to ``max_pulses``.
    """

    def __init__(self, turning_hz: float, max_pulses: float, slow_pulses: float = math.inf
                 ) -> None:
        self.turning_hz = turning_hz
        self.max_pulses = max_pulses
        self.slow_pulses = slow_pulses
        #: the last pulse at which the fan was seen turning at ``turning_hz`` or more
        self._turning_k: int | None = None
        self._held_k = 0                     # the pulse the hold began
        #: the slow hold ran out since the fan was last seen turning: not held slow again
        #: before it turns, but a rest that follows is still held from ``_turning_k``
        self._slow_spent = False

    def step(self, k: int, state: Decision, d: Decision, static: StaticRemover) -> bool:
        """After the decision ``d`` at pulse ``k`` and the state published from it: hold
        or release ``static``. True when its estimate, or whether it adapts, changed."""
        turning = (state.direction in WAYS or state.turning) \
            and (state.rate_hz or 0.0) >= self.turning_hz
        if turning:
            self._turning_k = k
            self._slow_spent = False
        if not static.frozen:
            if d.direction == Direction.STOPPED and self._turning_k is not None:
                held = [m for j, m in static.history if j <= self._turning_k]
                if held:
                    if static.normalise and static.gain_ref is None:
                        static.gain_ref = static.mean.copy()
                    static.mean[:] = held[-1]
                    static.frozen, static.held = True, False
                    self._held_k = k
                    return True
            slow = d.direction != Direction.STOPPED and d.rate_hz is not None \
                and math.isfinite(d.rate_hz) and d.rate_hz < self.turning_hz
            if not static.held and slow and self._turning_k is not None \
                    and not self._slow_spent:
                static.held = True
                self._held_k = k
                return True
            if static.held and (turning or k - self._held_k > self.slow_pulses):
                static.held = False
                # not held slow again before the fan turns again; a rest still is: a
                # spin-down from 0.25 Hz over 10 s stays slow longer than the slow hold,
                # and an estimate left to adapt through the rest took in the resting
                # blade, whose ghost then held a standing line for 10 s after the fan
                # started (spent held-out 1600010; 1600018 the same, 28 s with its
                # range-scale check)
                self._slow_spent = not turning
                return True
        elif turning or k - self._held_k > self.max_pulses:
            static.frozen = False
            self._turning_k = None          # not held again before the fan turns again
            self._slow_spent = False
            return True
        return False


class RateBound:
    """A fan seen at rest or turning at some speed cannot be turning much faster a moment
    later: a new line of the tracker (a lock, a re-check, an alias move) may not be
    faster than that speed plus twice the steepest ramp over the time since, plus twice
    the floor. Near rest the matches barely change, and a slow fan's matches jump to the
    mirror angle in its blind half-period: without the bound the tracker takes lines at
    alias rates (docs/dynamics.md, "Why each rule is there").

    A speed above three times the floor bounds only once it has been published for
    ANCHOR_TRUST_S (a first answer may be on a wrong line, and would keep out the right
    one); until then it bounds at UNTRUSTED_FACTOR times itself. A trusted speed also
    bounds from below, by the same ramp and floor: a new line may not be much slower.
    """

    def __init__(self, floor_hz: float, max_ramp_hz_s: float,
                 cycles_per_pulse: Callable[[float], float]) -> None:
        self.floor_hz = floor_hz
        self.max_ramp_hz_s = max_ramp_hz_s
        self._cycles = cycles_per_pulse      # Hz -> the tracker's cycles per pulse
        #: (time, rate in Hz) of the last known state published, trusted
        self._anchor: tuple[float, float] | None = None
        self._untrusted: tuple[float, float] | None = None   # (t, UNTRUSTED_FACTOR x speed)
        self._known_dir: Direction | None = None   # the published direction, and since when
        self._known_t = 0.0

    def step(self, t_s: float, state: Decision | None, tracker: Tracker) -> None:
        """After the state ``state`` published at ``t_s``: the tracker's bound on rates."""
        st = state
        if st is None or st.direction != self._known_dir:
            self._known_dir = None if st is None else st.direction
            self._known_t = t_s
        # a speed published with only its direction in doubt is known all the same (the
        # mirror image turns at the same speed): unbounded, a run in doubt let the
        # tracker take a far faster line as the fan came to rest, which held the stop
        # back (docs/dynamics.md, "The rate bound")
        if st is not None and (st.direction in (*WAYS, Direction.STOPPED) or (
                st.turning and st.rate_hz is not None and st.direction_doubt)):
            v = float(st.rate_hz or 0.0)
            if v <= 3.0 * self.floor_hz or t_s - self._known_t >= ANCHOR_TRUST_S:
                self._anchor, self._untrusted = (t_s, v), None
            else:
                self._untrusted = (t_s, UNTRUSTED_FACTOR * v)
        bound = math.inf
        for got in (self._anchor, self._untrusted):
            if got is not None:
                t0, v0 = got
                bound = min(bound, v0 + 2.0 * self.max_ramp_hz_s * max(t_s - t0, 0.0)
                            + 2.0 * self.floor_hz)
        tracker.limit_rate(self._cycles(bound) if math.isfinite(bound) else math.inf)
        # nor much slower: a line the matches of a look-alike angle make up, standing
        # nearly still, replaced a track on a spin-up at 0.5 Hz and drove the answer
        # through zero (spent held-out 800013, a false `reversed`)
        least = 0.0
        if self._anchor is not None:
            t0, v0 = self._anchor
            least = v0 - 2.0 * self.max_ramp_hz_s * max(t_s - t0, 0.0) - 2.0 * self.floor_hz
        tracker.rate_least = self._cycles(least) if least > 0.0 else 0.0


def _by_number(k: int, k0: int | None, group: int, first: bool, every: int
               ) -> tuple[bool, int, int]:
    """The daemon's cadence (``PulseAnalyzer.by_number``) at valid pulse ``k``: whether
    it is a decision's (the first of its run of ``every`` pulse numbers from ``k0``, or
    the first decision), and the first decision's pulse and the last decision's run
    after it. One rule for the block's planning ahead and for the decisions made."""
    if first or k0 is None:
        k0 = k
    g = (k - k0) // every
    if g == group and not first:
        return False, k0, group
    return True, k0, g


@dataclass
class PulseAnalyzer:
    """Streaming analysis of aligned pulses (what the daemon runs pulse by pulse).

    Feed blocks of :class:`AlignedPulses` to :meth:`process`; each returns per-pulse
    rows; :meth:`decision` gives the answer for the last ``window`` pulses. The last
    window's features are kept for the alias check (:mod:`dsp.aliasing`).
    """

    cfg: Config
    ref: Reference
    static: StaticRemover
    tracker: Tracker = field(init=False)
    motion: MotionMeter = field(init=False)
    window: int = field(init=False)
    _recent: list[tuple[bool, float]] = field(default_factory=list)  # (accepted, quality)
    #: the same as arrays (a decision reads the window's without building them from the
    #: list): the last _recent_n entries of each, oldest first, in room for a few windows
    _recent_acc: np.ndarray = field(init=False, repr=False)
    _recent_q: np.ndarray = field(init=False, repr=False)
    _recent_n: int = 0
    _prev: np.ndarray | None = None               # last raw pulse (for the noise level)
    noise: NoiseFloor = field(init=False)         # one pulse's noise energy (raw gate)
    dropped: int = 0
    seen: int = 0
    aliases: aliasing.AliasWatch = field(init=False)   # the alias check (dsp/aliasing.py)
    #: the state machine (transitions.py), its last output and events not yet taken
    transitions: Transitions = field(init=False)
    state: Decision | None = None
    #: capture stream sample of the pulse the state was decided on (the live pipeline
    #: predicts a changing rate from there to the present: LiveAnalyzer.estimate)
    state_edge: float | None = None
    new_events: list[Event] = field(default_factory=list)
    #: the decision cadence (tracking.decide_every): pulses since the last decision
    _since: int = 0
    #: the daemon's cadence (LiveAnalyzer): a decision on the first valid pulse of each
    #: run of decide_every pulse *numbers* from the first decision's (``_k0``; ``_group``
    #: the last decision's run), so that pulses dropped at a latency step move no later
    #: decision (counted over valid pulses they moved every one: a new noise draw on a
    #: ramp, docs/audio.md). With no pulse dropped, the same pulses as offline.
    by_number: bool = False
    _k0: int | None = None
    _group: int = -1
    #: the long meter's statistic at the last decision (the alias watch and the
    #: reference-fit watch read it between decisions)
    motion_fed: float = float("nan")
    decided: Decision | None = None               # the last decision (before the machine)
    _quiet: bool = False                          # the last decision's short meter was quiet
    #: (track, pulse) of the last decision whose short meter read motion while a track was
    #: locked: a quiet reading within the meter's window after it, on the same track, is
    #: the track's rate recurring at one of the meter's lags, not a rest
    _meter_moved: tuple[Any, int] | None = None
    _rest_moved: bool = False                     # the fan moved since the rest's hold began
    bursts: dev.BurstGate = field(default_factory=dev.BurstGate)   # pulses skipped: .bursts
    #: the locked track's unwrapped phase over the last window, (pulse, cycles), and the
    #: track it belongs to (a new lock or a move to another line starts it afresh)
    _restart_at: set[int] = field(default_factory=set)
    _carry_restart: set[int] = field(default_factory=set)
    _unwrapped: deque[tuple[int, float]] = field(default_factory=deque)
    _track_id: tuple[Any, ...] = ()
    #: the track's clear matches over the last RAMP_FIT_S, (pulse, phase unwrapped along
    #: the follower, quality), and the follower's last (pulse, unwrapped, wrapped) phase
    _fit: deque[tuple[int, float, float]] = field(default_factory=deque)
    _fit_at: tuple[int, float, float] | None = None
    _fit_span: int = field(init=False)              # RAMP_FIT_S in pulses
    #: range scale c_now / c_ref (dsp/rangescale.py): its estimate, the correlation it
    #: rests on, and the rescaler of features when it is used
    scale: float = 1.0
    scale_corr: float = 1.0
    _rescale: rangescale.Rescaler | None = None
    _scale_due: int = 0
    #: the last pulse published stopped: the static estimate then holds the blade at
    #: rest, not the room's mean over a rotation the reference's is (check_scale)
    _stopped_k: int | None = None
    #: a recording read from a file: samples lost in a drop-out leave no count of the
    #: pulses lost (the daemon counts them from the capture position), so nothing is
    #: carried across one that a jump of unknown length would spoil (_restart_track)
    uncertain_gaps: bool = False
    restarts: int = 0
    #: the feedback after each step of the state machine (_feed_back)
    rest_hold: RestHold = field(init=False)
    rate_bound: RateBound = field(init=False)

    def __post_init__(self) -> None:
        self.tracker = Tracker(tracker_settings(self.cfg, self.ref))
        self.transitions = Transitions(transition_settings(self.cfg), self.cfg.prf_hz)
        c = self.cfg.tracking
        turning_hz = 3.0 * c.rate_floor_hz
        spinup = max(self.transitions.settings.min_spinup_hz_s, 1e-9)
        self.rest_hold = RestHold(turning_hz, HOLD_S * self.cfg.prf_hz,
                                  slow_pulses=2.0 * turning_hz / spinup * self.cfg.prf_hz)
        self.rate_bound = RateBound(c.rate_floor_hz, c.max_ramp_hz_s, self._cycles_per_pulse)
        self._decide_settings = decide_settings(self.cfg)
        self.window = max(int(round(self.cfg.daemon.window_s * self.cfg.prf_hz)), 20)
        self._fit_span = max(int(round(RAMP_FIT_S * self.cfg.prf_hz)), 2 * RAMP_FIT_LEAST)
        self.noise = NoiseFloor(NOISE_FALL, self.window)
        self._recent_acc = np.zeros(4 * self.window)
        self._recent_q = np.zeros(4 * self.window)
        # lags up to the blade period at the slowest rate followed (reference rate / slew
        # limit): at some lag within it a moving pattern recurs
        slowest = self.ref.cycles_per_pulse / self.cfg.tracking.slew_limit
        lags = int(math.ceil(1.2 / max(slowest, 1e-6)))
        self.motion = MotionMeter(self.ref.table.shape[1], self.window,
                                  max_lag=max(4, min(lags, self.window // 2)))
        # lags that cannot reach one blade period at the reference rate never see a moving
        # pattern recur and read it as no change: such a window gives no stopped verdict
        self._lags_short = self.motion.max_lag < math.ceil(1.2 / self.ref.cycles_per_pulse)
        # the fan coming to rest must show within seconds: a short meter on envelope
        # features of the pulses minus a slow static estimate (the 3 s one adapts to a
        # stopped fan, which itself looks like motion), band-limited (process())
        short = max(int(round(STILL_WINDOW_S * self.cfg.prf_hz)), 8)
        self.still = MotionMeter(self.ref.mean_pulse.shape[0], short,
                                 max_lag=max(3, min(lags, short // 2)))
        self.slow = StaticRemover(self.static.alpha / SLOW_FACTOR, self.static.mean)
        self._still_level = float(low_band_norms(self.slow.mean[None, :])[0])
        # the short meter calls rest against what noise alone reads in this gate (a short
        # gate reads well over 1: decide.noise_threshold), never below the configured one
        floor = self._decide_settings.motion_threshold
        shape = (self.ref.mean_pulse.shape[0], self.still.window, self.still.max_lag,
                 STILL_BAND, self.cfg.analysis.envelope_smooth)
        noise_high = noise_threshold(*shape) + NOISE_MARGIN
        self._decide_settings = replace(self._decide_settings,
                                        still_threshold=max(floor, noise_high))
        # and above what this device reads at rest, where that is more than noise
        noise_median = noise_threshold(*shape, quantile=0.5)
        self.rest_floor = RestFloor(self._decide_settings.still_threshold, noise_median,
                                    REST_SHIFT_MAX, REST_KEEP, REST_LEAST)
        # and under it, as far as this fan turning reads it (a far fan barely moves it)
        self.turning_floor = TurningFloor(noise_high, noise_median, TURNING_QUANTILE,
                                          REST_KEEP, REST_LEAST)
        self.accept_floor = AcceptFloor(ACCEPT_LEAST_SHARE, ACCEPT_KEEP, ACCEPT_LEAST)
        self._table_norms = (self.ref.table ** 2).sum(axis=1)
        self._table_floor = fp.distance_floor(self.ref.table)
        tw = self.ref.meta.get("twin_bins")
        self._twins = np.asarray(tw, dtype=np.int64) if tw else None
        prf = self.cfg.prf_hz
        self.aliases = aliasing.AliasWatch(
            aliasing.fine_table(self.ref.table), self.window, self.ref.cycles_per_pulse,
            min_rate=self.ref.cycles_per_pulse / self.cfg.tracking.slew_limit,
            ramp_accel=self._decide_settings.changing_hz_s * self.cfg.scene.blades / prf ** 2)
        contrast = self.ref.meta.get("direction_contrast")
        if isinstance(contrast, (int, float)) and contrast < aliasing.MIRROR_DOUBT_Z:
            # the reference's own pulses barely told their direction from its mirror:
            # every track's direction waits for its own evidence from the start
            self.aliases.mirror_doubt = 1.0

    def process(self, block: AlignedPulses, *, rows: bool = False) -> list[dict[str, Any]]:
        """Match and track every pulse of a block; measure motion and decide every
        ``tracking.decide_every`` valid pulses (on the same pulses offline as in the
        daemon, whatever the blocks); optional per-pulse rows carrying the last state.
        Events confirmed in the block are added to ``new_events``."""
        # a block's static removal runs ahead of its pulses' decisions; a decision that
        # changes the static estimate (RestHold) rewinds to here, so that the rest of
        # the block is removed with the new estimate, as the daemon's next pulse is
        saved = self._streams() if int(np.count_nonzero(block.valid)) > 1 else None
        prep = self._prepare(block)
        if prep is None:
            return []
        v, xv, feats, m, dist, still_feats = prep
        out: list[dict[str, Any]] = []
        fs = self.cfg.audio.sample_rate
        every = self.cfg.tracking.decide_every
        # the meters' statistics at the block's decisions, in a few matrix products (the
        # pulses are added to the meters once the block is done)
        at: dict[int, int] = {}
        since, first = self._since, self.state is None
        ks = block.index[v].tolist()
        group, k0 = self._group, self._k0
        for i in range(len(feats)):
            since += 1
            if self.by_number:
                hit, k0, group = _by_number(ks[i], k0, group, first, every)
                if hit:
                    at[i + 1], first = len(at), False
            elif since >= every or first:
                at[i + 1], since, first = len(at), 0, False
        ends = np.fromiter(at, dtype=np.int64, count=len(at))
        pm, ps = self.motion.preview(feats, ends), self.still.preview(still_feats, ends)
        # Python's numbers, not numpy's scalars, in the loop (the same values)
        phases, quals = m.phase.tolist(), m.quality.tolist()
        twins = [math.nan] * len(phases) if self._twins is None else \
            fp.twin_phases(m.phase, self._twins).tolist()
        # each pulse's half lag-1 difference energy (the noise level), for the block at
        # once: np.vecdot's rows are the vector products ``dd @ dd`` (the same bits)
        # (a block's first pulse against the last one before it; xv has a pulse at least)
        dd = np.empty_like(xv)
        if self._prev is not None:
            np.subtract(xv[0], self._prev, out=dd[0])
        else:
            dd[0] = 0.0                      # (not read: no pulse before it)
        np.subtract(xv[1:], xv[:-1], out=dd[1:])
        lag1 = np.vecdot(dd, dd).tolist()
        del dd
        for i, (k, edge) in enumerate(zip(block.index[v].tolist(), block.edges[v].tolist(),
                                          strict=True)):
            if k in self._restart_at:
                self._restart_track()
            st = self.tracker.update(k, phases[i], quals[i], twins[i])
            self._follow_phase(k, st)
            tr = self.tracker
            fph = tr.follower_phase
            self.aliases.push(k, dist[i], math.nan if not st.locked else
                              fph if fph is not None else st.phase)
            self._check_aliases()
            if self.aliases.count % RECHECK_EVERY == 0:
                self._recheck_track()
            if self._prev is not None:
                self.noise.update(lag1[i])
            self._prev = xv[i]
            self._note_match(not st.outlier and st.locked, quals[i])
            t_s = edge / fs
            self._since += 1
            fired: list[Event] = []
            changed = False
            if self._decides(k, every):
                # counted over all valid pulses (or on pulse numbers: by_number), so
                # that the daemon (blocks of 8) and analyze (large blocks) decide on
                # the same pulses
                q = at[i + 1]
                self.motion_fed = float(pm.motion[q])
                self._let_go_at_start(float(ps.motion[q]))
                d = self.decided = self.decision((self.motion_fed, float(ps.motion[q])))
                state, fired = self.transitions.step(
                    t_s, k, d, self._since, quiet=self._quiet,
                    line=self.tracker.identity if self.tracker.locked else None)
                state, changed = self._feed_back(k, t_s, d, state)
                self.state = self.transitions.carry(
                    t_s, state, self.tracker.identity if self.tracker.locked else None)
                self._stopped_k = k if self.state.direction == Direction.STOPPED \
                    else self._stopped_k
                self.state_edge = edge
                self.new_events.extend(fired)
                self._since = 0
            if rows:
                row: dict[str, Any] = {"t_s": round(t_s, 4), "pulse": k,
                       "phase": round(phases[i], 4),
                       "quality": round(quals[i], 4),
                       "track_phase": None if not st.locked else round(st.phase, 4),
                       "track_sd": None if not st.locked or self.tracker.P is None else round(
                           math.sqrt(max(self.tracker.P.item(0, 0), 0.0)), 5),
                       "outlier": st.outlier}
                assert self.state is not None       # (decided on the first pulse)
                row.update(self.state.as_dict())
                row["event"] = fired[-1].kind if fired else None
                out.append(row)
            if changed and saved is not None:
                after = block.index > k
                if np.any(after & block.valid):
                    self.motion.commit(pm, i + 1)
                    self.still.commit(ps, i + 1)
                    out.extend(self._redo_rest(block, k, saved, rows))
                    return out
        self.motion.commit(pm)
        self.still.commit(ps)
        return out

    def _decides(self, k: int, every: int) -> bool:
        """Whether valid pulse ``k`` is a decision's (see ``by_number``)."""
        if not self.by_number:
            return self._since >= every or self.state is None
        hit, self._k0, self._group = _by_number(k, self._k0, self._group,
                                                self.state is None, every)
        return hit

    def next_decision(self, nth: int = 1) -> int | None:
        """With ``by_number``: the number of the pulse the next decision falls on if it
        is valid, or with ``nth`` the next of every nth decision (the daemon ends its
        analysis blocks there); None before the first decision."""
        if not self.by_number or self._k0 is None:
            return None
        nth = max(int(nth), 1)
        return self._k0 + (self._group // nth + 1) * nth * self.cfg.tracking.decide_every

    def _prepare(self, block: AlignedPulses) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                      fp.Matches, np.ndarray, np.ndarray] | None:
        """What a block needs before its pulses are tracked: the counts, the restart
        marks after drop-outs, static removal (bursts skipped), envelope features, the
        matches and the distances for the alias check. None without a usable pulse."""
        a = self.cfg.analysis
        v = block.valid
        self.seen += len(block)
        self.dropped += int(np.count_nonzero((block.status != OK) & (block.status != WARMUP)))
        if not v.any():
            return None
        if self.uncertain_gaps and (block.status == DROPOUT).any():
            # pulses after a drop-out: the first valid one starts a new track
            after = np.zeros(len(block), bool)
            for j in np.nonzero(block.status == DROPOUT)[0]:
                nxt = np.nonzero(v[j + 1:])[0]
                if len(nxt):
                    after[j + 1 + nxt[0]] = True
            self._restart_at = set(block.index[after].tolist())
        else:
            self._restart_at = set()
        self._restart_at |= self._carry_restart
        self._carry_restart = set()
        xv, res, burst = self.static.skip_bursts(block.pulses[v], self.bursts, block.index[v])
        if burst.any():
            # swamped by interference: skipped (and counted by the gate), like a drop-out
            v = v.copy()
            v[np.nonzero(v)[0][burst]] = False
            xv, res = xv[~burst], res[~burst]
            if not v.any():
                return None
        feats = fp.envelope_features(res, None, kind=a.features, smooth=a.envelope_smooth)
        self._scale_due -= len(xv)
        if self._scale_due <= 0 and self._holds_room_mean(int(block.index[v][0])):
            self.check_scale(self.static.mean)
        if self._rescale is not None:
            feats = self._rescale(feats)
        m = fp.match(feats, self.ref.table, self._table_norms, self._table_floor)
        dist = aliasing.distances(feats, self.aliases.fine)
        # (under normalise, at a scale that does not follow the adapting estimate)
        still_in = at_one_level(xv, self._still_level) if self.static.normalise else xv
        still_feats = fp.envelope_features(self.slow(still_in), None, kind="envelope",
                                           smooth=a.envelope_smooth, band=STILL_BAND)
        return v, xv, feats, m, dist, still_feats

    def _streams(self) -> tuple[Any, ...]:
        """The state the static removal of a block moves (for _redo_rest)."""
        return (self.static.copy(), self.slow.copy(), self.bursts.copy(),
                self._scale_due, self.scale, self.scale_corr, self._rescale, self.seen,
                self.dropped)

    def _redo_rest(self, block: AlignedPulses, k: int, saved: tuple[Any, ...], rows: bool
                   ) -> list[dict[str, Any]]:
        """The static estimate changed at pulse ``k`` of ``block``: the streams go back
        to the block's start and run again over its pulses up to ``k`` (the same
        results), the change is made again, and the rest of the block is processed with
        it."""
        changed_static = (self.static.mean.copy(), self.static.frozen, self.static.held)
        made_ref = self.static.gain_ref is not None
        restart = self._restart_at
        (self.static, self.slow, self.bursts, self._scale_due, self.scale, self.scale_corr,
         self._rescale, self.seen, self.dropped) = saved
        head = block.index <= k
        self._prepare(_rows_of(block, head))
        if made_ref and self.static.gain_ref is None:
            # a first hold's gain reference is the estimate after pulse k, as a pulse at a
            # time has it (not the block's end, which the first pass had reached)
            self.static.gain_ref = self.static.mean.copy()
        if changed_static[1] and not self.static.frozen:
            # a rest's hold began at k: it put another estimate in
            self.static.mean[:] = changed_static[0]
        # (otherwise the estimate after pulse k stands: the first pass had adapted it
        # over the whole block, and only whether it adapts changed at k)
        self.static.frozen, self.static.held = changed_static[1:]
        # a drop-out at the head's end marks the rest's first pulse
        self._carry_restart = {j for j in restart if j > k}
        return self.process(_rows_of(block, ~head), rows=rows)

    def _let_go_at_start(self, still: float) -> None:
        """While a rest's hold is on and `stopped` is published, the first short-meter
        reading of motion (over ``START_STILL`` times the rest threshold) gives up the
        track that stood through the rest: a new lock is fitted from the recent matches
        (not at a reversal's zero, whose track goes on through it).

        Why: at rest a still pattern fits an angle and its mirror alike, and the track
        that stood there took the fan's first moves from whichever it sat on. In spent
        held-out 3700012 (3 blades 3.2 m away) the first clear matches of two starts lay
        on the mirror branch, the standing track followed them the wrong way, and
        `started` came `reversed` within a second, although the matches on the true
        branch were as many and as clear; a lock fitted on the recent matches weighs
        them all."""
        if not self.static.frozen:
            self._rest_moved = False
        elif not self._rest_moved and self.state is not None \
                and self.state.direction == Direction.STOPPED \
                and still > START_STILL * self._decide_settings.still_threshold:
            self._rest_moved = True
            self.tracker.let_go()

    def _restart_track(self) -> None:
        """After a drop-out of unknown length: the track goes on (most drop-outs lose less
        than a PRI, and then nothing changed), but a lock taken from now on uses only
        matches after the gap (a line through matches on both sides of a hidden jump
        of n PRIs has a wrong rate), and the window's mean rate starts afresh."""
        self.tracker.forget_matches()
        self._unwrapped.clear()
        self._fit.clear()
        self._fit_at = None
        self.restarts += 1

    def _holds_room_mean(self, k: int) -> bool:
        """Whether the static estimate at pulse ``k`` may be the mean pulse the
        reference's is compared with: adapting (not held for a rest or a slow fan), and
        a window past the last pulse published stopped. At rest it holds the blade at one
        angle, and against the reference's mean over a rotation the range scale read
        -4.5 % (spent held-out 1600018): a fan that started then was unknown ("record a
        new reference") for 28 s, until the next check. Not more than that: a scale
        misread while a fast fan turned (1.4 %, 1600019) was mended by the next check,
        and one put off while the answers were unknown spoilt 97 s."""
        return not (self.static.frozen or self.static.held) and (
            self._stopped_k is None or k - self._stopped_k > self.window)

    def check_scale(self, static_mean: np.ndarray) -> None:
        """(Re-)estimate the range scale against the reference's static room; features are
        rescaled while it is off 1 but within SCALE_LIMIT. A scale beyond it is checked
        again a window later rather than SCALE_EVERY: it makes every answer unknown."""
        g = self.ref.gate
        s, corr = rangescale.estimate_scale(self.ref.mean_pulse, static_mean, g.start)
        self.scale, self.scale_corr = s, corr
        self._scale_due = SCALE_EVERY if not self.scale_misfit else self.window
        r = rangescale.Rescaler(s, g.start, g.length)
        self._rescale = r if r.active and corr >= SCALE_MIN_CORR and \
            rangescale.within(s, SCALE_LIMIT) else None

    @property
    def scale_misfit(self) -> str:
        """Why the reference no longer fits the room ('' while it does)."""
        if self.scale_corr >= SCALE_MIN_CORR and not rangescale.within(self.scale, SCALE_LIMIT):
            dT = rangescale.degrees(self.scale, self.ref.gate.c)
            return (f"the room's echoes have moved by {100 * (self.scale - 1):+.1f} % "
                    f"(sound {abs(dT):.0f} degrees C {'warmer' if dT > 0 else 'colder'} than "
                    "at the reference, or the room changed): record a new reference")
        return ""

    def _follow_phase(self, k: int, st: TrackState) -> None:
        """Unwrap the track's phase pulse by pulse (the window's mean rate, below)."""
        tr = self.tracker
        tid = tr.identity
        if not st.locked or tid != self._track_id:
            self._unwrapped.clear()
            self._fit.clear()
            self._fit_at = None
            self._track_id = tid
            if not st.locked:
                return
        self._note_fit(k, st)
        h = self._unwrapped
        if h:
            k0, u0 = h[-1]
            step = float(st.rate) * (k - k0) if math.isfinite(st.rate) else 0.0
            d = st.phase - (u0 % 1.0) - step
            h.append((k, u0 + step + d - round(d)))
            while h and h[0][0] <= k - self.window:
                h.popleft()
        else:
            h.append((k, float(st.phase)))

    def _note_fit(self, k: int, st: TrackState) -> None:
        """Keep pulse ``k``'s match for :meth:`ramp_rate` if it is clear and on the
        track's line, its phase unwrapped along the follower's (a changing rate's own
        line: on a ramp the constant-rate track runs ahead of the fan between bursts)."""
        f = self.tracker.follower_phase
        if f is None:
            self._fit.clear()
            self._fit_at = None
            return
        last = self._fit_at
        u = f if last is None else last[1] + wrap(f - last[2])
        self._fit_at = (k, u, f)
        r = wrap(st.z - f)
        if st.quality >= self.tracker.settings.min_info and not st.outlier \
                and abs(r) < MAX_INNOVATION:
            self._fit.append((k, u + r, st.quality))
        while self._fit and self._fit[0][0] <= k - self._fit_span:
            self._fit.popleft()

    def ramp_rate(self) -> float | None:
        """A changing rate read from the track's clear matches of the last RAMP_FIT_S
        (cycles per pulse): the slope at the latest pulse of a quadratic through their
        phases, each weighed by its quality as the filters weigh it. The follower's
        rate swings with each burst of matches where they come in bursts; the fit
        averages the bursts of two seconds. None with too few matches or too short a
        span of them."""
        pts, at, span = self._fit, self._fit_at, self._fit_span
        if at is None or len(pts) < RAMP_FIT_LEAST or pts[-1][0] - pts[0][0] < span // 2:
            return None
        a = np.array(pts)
        rate = parabola_slope(a[:, 0], a[:, 1], a[:, 2], at[0], span)
        return rate if math.isfinite(rate) else None

    def window_rate(self) -> float | None:
        """The mean phase rate over the last window (cycles per pulse): the unwrapped
        track's advance over it, from the window's start to its end. A fan whose speed
        wobbles reads its mean here, where the tracked rate is the latest one and lags a
        wobble; None until the track spans half a window."""
        h = self._unwrapped
        if len(h) < 4 or h[-1][0] - h[0][0] < self.window // 2:
            return None
        (k0, u0), (k1, u1) = h[0], h[-1]
        km, um = h[len(h) // 2]
        if not (k0 < km < k1):
            return None
        mean = (u1 - u0) / (k1 - k0)
        # a trend is no wobble: halves whose rates differ by more than TREND_SHARE of the
        # mean are a ramp, where the latest rate is the answer and the mean lags it
        r1, r2 = (um - u0) / (km - k0), (u1 - um) / (k1 - km)
        if abs(r2 - r1) > TREND_SHARE * abs(mean):
            return None
        return mean

    def _note_match(self, accepted: bool, quality: float) -> None:
        """Keep a pulse's match (accepted by the track, its quality) for the window."""
        self._recent.append((accepted, quality))
        if len(self._recent) > self.window:
            del self._recent[0]
        n = self._recent_n
        if n == len(self._recent_q):             # full: the last window to the front
            keep = self.window - 1
            self._recent_acc[:keep] = self._recent_acc[n - keep:n]
            self._recent_q[:keep] = self._recent_q[n - keep:n]
            n = keep
        self._recent_acc[n] = 1.0 if accepted else 0.0
        self._recent_q[n] = quality
        self._recent_n = n + 1

    def recent_match(self) -> tuple[float, float]:
        """(share of the last window's matches the track accepted, their mean match
        quality); NaN before any match. The daemon's reference-fit watch reads it."""
        if not self._recent:
            return math.nan, math.nan
        n = len(self._recent)
        return (sum(1.0 for a, _ in self._recent if a) / n,
                sum(q for _, q in self._recent) / n)

    def _seen_still(self) -> bool:
        """Whether the matches show the blade standing still in view: a track older than
        its lock's matches, slower than half the floor by two standard deviations, that
        accepted nearly all of the recent informative matches (with the static estimate
        held while the fan rests, a blade at rest in view matches its angle clearly). A
        fan reversing slowly through zero in view moves its matches, and the short meter
        sees it too (1.5 s of 0.02 Hz read 7.7 against its 1.15 for rest)."""
        tr = self.tracker
        st = tr.settings
        if not tr.locked or tr.start_k is None or tr.last_k is None \
                or tr.last_k - tr.start_k < 2 * st.init_pulses:
            return False
        floor = self._cycles_per_pulse(0.5 * self._decide_settings.rate_floor_hz)
        rate, var = tr.track_rate
        sd = math.sqrt(max(var, 0.0))
        if abs(rate) + 2.0 * sd >= floor:
            return False
        recent = self._recent[-st.init_pulses:]
        w = [q * q for _, q in recent]
        if not recent or max(q for _, q in recent) < st.min_info or not sum(w) > 0:
            return False
        return sum(wi for wi, (acc, _) in zip(w, recent, strict=True) if acc) >= 0.8 * sum(w)

    def _unseen_s(self) -> float:
        """Seconds since the track last accepted a clear match (0 without a track): what
        it has answered since is its prediction (Decision.unseen_s)."""
        tr = self.tracker
        if not tr.locked or tr.clear_k is None or tr.last_k is None:
            return 0.0
        return max(tr.last_k - tr.clear_k, 0) / self.cfg.prf_hz

    def _cycles_per_pulse(self, hz: float) -> float:
        """A rotation rate in Hz as the tracker's blade cycles per pulse (by the
        reference's own rate and cycles per pulse)."""
        return hz / float(self.ref.meta["rate_hz"]) * self.ref.cycles_per_pulse

    def _feed_back(self, k: int, t_s: float, d: Decision, state: Decision
                   ) -> tuple[Decision, bool]:
        """The one place the answer flows back into the analysis, after each step of the
        state machine: the published rate (:meth:`_reported_rate`), the static estimate
        held while the fan rests (:class:`RestHold`), the bound on the tracker's new
        lines (:class:`RateBound`), and the tracker told that a fan at rest may start any
        moment. (The state to publish, whether the static estimate changed: the rest of
        the block is then removed with the new one, :meth:`_redo_rest`.)"""
        published = self._reported_rate(state)
        changed = self.rest_hold.step(k, published, d, self.static)
        self.rate_bound.step(t_s, published, self.tracker)
        # a fan not confirmed at rest may pass zero out of sight and come back the other
        # way: a track that stood through that gap on the known way's side is no
        # evidence of it (Tracker._stood_blind)
        known = self.transitions.known
        self.tracker.known_way = 0.0 if known not in WAY_KINDS else math.copysign(
            1.0, self.ref.cycles_per_pulse) * (1.0 if known == Kind.SAME else -1.0)
        if self.static.frozen:
            self.tracker.expect_change()     # a fan at rest may start any moment
        return published, changed

    def _reported_rate(self, d: Decision) -> Decision:
        """The rate a turning state reports. The latest rate is the follower's (it
        follows a change of speed as soon as the matches show it); a changing one is
        its mean with :meth:`ramp_rate`'s (where matches come in bursts the follower
        swings with each, and the fit through two seconds of them lags a ramp's knees:
        on spent held-out 5100001-20 each alone was the worse in some rooms, the mean
        took the pooled ramp p95 from 10.4 to 9.2 %); a settled fan reads
        its window's mean instead (a wobble of a few per cent averages out), or the
        quieter track's rate before the window is full, but only while that agrees with
        the latest rate within SETTLED_AGREE: at the onset of a ramp both still hold the
        old speed for a second or more while the follower already has the new one. Only
        what is published changes: the state machine decides on the
        decision's own rate (the follower is the livelier of the two, and after a
        spurious lock near rest its rate alone would clear the rate needed for a new
        direction)."""
        if d.direction not in WAYS or d.relative_rate is None:
            return d
        tr = self.tracker
        if not tr.locked:
            return d
        now, _ = tr.rate_now
        rate = now
        if d.rate_state == RateState.CHANGING:
            fit = self.ramp_rate()
            if fit is not None and fit * now > 0:
                rate = 0.5 * (now + fit)
        elif d.rate_state == RateState.SETTLED:
            mean = self.window_rate()
            steady = mean if mean is not None else tr.track_rate[0]
            if steady * now > 0 and abs(steady - now) <= SETTLED_AGREE * abs(steady):
                rate = steady
        if not (math.isfinite(rate) and rate * d.relative_rate > 0):
            return d
        rel = rate / self.ref.cycles_per_pulse
        hz = abs(rel) * float(self.ref.meta["rate_hz"])
        if hz < self._decide_settings.rate_floor_hz:
            # a direction is claimed, so the fan turns at least that fast: the latest rate
            # has drifted under it; the decision's own rate stands
            return d
        return d.replaced(relative_rate=rel, rate_hz=hz, rpm=hz * 60.0)

    def take_events(self) -> list[Event]:
        """Events confirmed since the last call (the daemon publishes them)."""
        got, self.new_events = self.new_events, []
        return got

    def _check_aliases(self) -> None:
        """The alias watch (:class:`aliasing.AliasWatch`) on the current track; it needs
        the long meter only for a track standing still (checked while the fan moves)."""
        d = self.decided
        # a held static estimate (RestHold) stands for a fan at rest only until a turn is
        # decided at a clear rate: held on until a published turn released it, the check
        # a sudden turn waits for never ran, and the turn was never published (spent
        # held-out 700002: a reversal through zero held `unknown` for 20 s and missed)
        resting = self._quiet or (d is not None and d.direction == Direction.STOPPED) or (
            self.static.frozen and not (
                d is not None and (d.direction in WAYS or d.turning)
                and (d.rate_hz or 0.0) >= self.rest_hold.turning_hz))
        # (the acceleration and the meter asked only when a check is due)
        self.aliases.check(self.tracker, accel=self._clear_accel, moving=self._moving,
                           resting=resting)

    def _moving(self) -> bool:
        """Whether the long meter sees the fan move (at its last decision)."""
        return self.motion_fed >= self.cfg.tracking.motion_threshold

    def _recheck_track(self) -> None:
        """A track the good matches mostly reject is given up for a line that fits them
        (:meth:`Tracker.recheck`); near p/q cycles per pulse only for a line that is not
        one of its aliases, among which the alias check chooses. Not a track the alias
        watch has verified (it followed a ramp, or a steady rate near no p/q, over
        seconds): the re-check is for a lock taken on a wrong line, and at the edge of a
        slow fan's blind half-period the matcher jumps to the mirror angle at high
        quality often enough to outweigh the clear matches a right track accepts."""
        tr = self.tracker
        if not tr.locked or self.aliases.verified == tr.identity:
            return
        assert tr.last_k is not None   # locked
        rate, var = tr.track_rate
        sd = math.sqrt(max(var, 0.0))
        span = int(tr.last_k - tr.start_k) + 1 if tr.start_k is not None else self.window
        fracs = aliasing.near_fractions(rate, span=span, rate_std=sd,
                                        accel=self._clear_accel())
        aliases = None
        if fracs:
            if fracs[0] == 0:
                return       # a track standing still: every p/q is its alias
            aliases = aliasing.alias_rates(rate, fracs, max_rate=tr.max_rate,
                                           min_rate=0.0)
        if tr.recheck(aliases):
            # the old line's rejections say nothing about the new one
            self._recent.clear()
            self._recent_n = 0

    def _clear_accel(self) -> float:
        """The tracked acceleration beyond twice its standard deviation (0 when it could be
        noise), cycles per pulse per pulse."""
        a, sd = self.tracker.accel
        return max(abs(a) - 2.0 * sd, 0.0) if math.isfinite(sd) else 0.0

    def decision(self, meters: tuple[float, float] | None = None) -> Decision:
        """The answer for the last ``window`` pulses (up to the last pulse fed);
        ``meters``: the long and short meters' statistics there (process() has them from
        its block's preview), else read from the meters."""
        motion, still = meters if meters is not None else (self.motion.statistic()[0],
                                                           self.still.statistic()[0])
        if motion < self.cfg.tracking.motion_threshold and self._lags_short:
            motion = float("nan")   # no verdict on motion (see __post_init__)
        # scene: static echo energy over the noise per pulse (raw domain); while nothing
        # changes between pulses, lag-1 differences of raw pulses are pure noise
        st = self.static.mean
        noise = self.noise.energy
        scene = float(st @ st) / noise if noise > 0 else float("nan")
        n = self._recent_n
        acc = self._recent_acc[n - len(self._recent):n]
        qual = self._recent_q[n - len(self._recent):n]
        # share of the informative matches that the track accepted, each weighted like the
        # filter weighs it (1 / measurement variance, i.e. quality squared)
        wq = qual * qual
        wsum = wq.sum()
        accepted = float((acc * wq).sum() / wsum) if wsum > 1e-12 else 0.0
        locked = self.tracker.locked
        rate, sd = self.tracker.rate
        tr = self.tracker
        settled = locked and tr.start_k is not None and tr.last_k is not None \
            and tr.last_k - tr.start_k >= self.window and math.isfinite(rate) \
            and abs(rate) >= ACCEPT_CLEAR_SD * sd
        accepted = self.accept_floor.note(accepted, settled)
        prf = self.cfg.prf_hz
        accel, _ = self.tracker.accel
        # the short meter's threshold, calibrated on its readings while the tracker sees
        # no motion (RestFloor)
        ref_cpp = self.ref.cycles_per_pulse
        seen_hz = abs(rate) / ref_cpp * float(self.ref.meta["rate_hz"]) \
            if locked and math.isfinite(rate) and ref_cpp > 0 else 0.0
        thr = self.rest_floor.note(still, seen_hz < self.cfg.tracking.rate_floor_hz)
        shown = self.state
        self.turning_floor.note(still, shown is not None and shown.direction in WAYS
                                and (shown.rate_hz or 0.0) >= self.rest_hold.turning_hz
                                and not (self.static.frozen or self.static.held))
        thr = self.turning_floor.cap(thr, self.rest_floor.rest_median)
        if thr != self._decide_settings.still_threshold:
            self._decide_settings = replace(self._decide_settings, still_threshold=thr)
        # the short meter sees no change beyond noise: the fan may be coming to rest, and
        # a track coasting on is no direction to check against its mirror
        self._quiet = still < self._decide_settings.still_threshold
        # a track the short meter saw moving moments ago: a quiet reading now is its rate
        # recurring at one of the meter's lags (the meter reads the least change over its
        # lags), not the fan stopped; where the rate recurs a quiet meter outweighs a
        # track only after a window of quiet (spent held-out 5700013: a steady 1.44 Hz fan
        # at 1/6 blade period per pulse read 1.0 for 0.6 s between readings of 3-500, and
        # was published stopped and started again)
        last_k = tr.last_k
        if locked and last_k is not None and not self._quiet:
            self._meter_moved = (tr.identity, last_k)
        moved = self._meter_moved
        recurring_seen = locked and last_k is not None and moved is not None \
            and moved[0] == tr.identity and last_k - moved[1] <= self.still.window \
            and not self.transitions.near_zero_since_known
        # a fan seen at rest: its static estimate held, or its rest confirmed (a rest that
        # comes more than SNAPSHOTS after the fan last turned briskly finds no copy of
        # the estimate to hold, and there a lock on the resting blade at 0.11 Hz, the
        # short meter quiet at 1.00-1.03, was published as a start 0.9 s after the stop:
        # held-out 5300002, spent); a fan that starts moves its echoes for the meter
        at_rest = self.static.frozen or self.transitions.known == Kind.STOPPED
        args: dict[str, Any]       # (decide's keywords, given twice below)
        args = dict(still=still, accel=accel * prf,
                    changing_odds=self.tracker.follower_weight,
                    at_rest=at_rest, seen_still=self._seen_still(),
                    still_lags=0 if recurring_seen else self.still.max_lag, rate=rate,
                    rate_std=sd, locked=locked,
                    accepted=accepted,
                    # (numpy's mean is this sum over the count, at twice the cost)
                    quality=float(qual.sum()) / len(qual) if len(qual) else 0.0,
                    motion=motion, scene=scene,
                    ref_cycles_per_pulse=self.ref.cycles_per_pulse,
                    ref_rate_hz=float(self.ref.meta["rate_hz"]),
                    ref_direction=self.ref.meta.get("direction", "unknown"),
                    alias_gap=self.aliases.verdict.gap if locked and self.aliases.verdict
                    else math.inf,
                    alias_note=self.aliases.note if locked else "",
                    direction_note=self.aliases.mirror_note if locked else "",
                    awaiting_check=locked and self.aliases.awaiting_check,
                    settings=self._decide_settings)
        d = decide(**args)
        mean = self.window_rate()
        if d.rate_state == RateState.SETTLED and d.relative_rate is not None \
                and mean is not None and mean * rate > 0:
            # settled: the window's mean rate (a wobble of a few per cent averages out; the
            # tracked rate is the latest and lags it); a changing one is the follower's
            args["rate"] = mean
            d = decide(**args)
        d = d.replaced(mirror_checked=locked and self.aliases.mirror_checked(self.tracker),
                       doubtful_room=self.aliases.doubtful, unseen_s=self._unseen_s(),
                       standing_alias=locked and self.aliases.standing)
        misfit = self.scale_misfit
        if misfit and d.direction in WAYS:
            return Decision(Direction.UNKNOWN, None, d.relative_rate, d.rate_hz, d.rpm,
                            min(d.confidence, self._decide_settings.min_confidence) * 0.5,
                            misfit, d.warnings)
        if self._rescale is not None and not any("rescaled" in w for w in d.warnings):
            d = replace(d, warnings=(
                *d.warnings,
                f"the room's echoes moved by {100 * (self.scale - 1):+.2f} % (about "
                f"{rangescale.degrees(self.scale, self.ref.gate.c):+.0f} degrees C since the "
                "reference): ranges rescaled to the reference's"))
        return d


def new_analyzer(cfg: Config, ref: Reference, first: np.ndarray | None = None) -> PulseAnalyzer:
    """A streaming analyzer; ``first`` (n, L) primes the static estimate (warm-up)."""
    check_compatible(ref, cfg)
    w = max(cfg.analysis.static_window_s * cfg.prf_hz, 1.0)
    mean = ref.mean_pulse if first is None or len(first) == 0 else np.mean(first, axis=0)
    static = StaticRemover(1.0 / w, mean)
    # (a reference file's metadata is checked for what it must hold, not for this optional
    # figure: a device entry that is not a table, or a wander that is not a number, is none)
    device = ref.meta.get("device")
    wander = device.get("gain_wander_db") if isinstance(device, dict) else None
    static.normalise = isinstance(wander, (int, float)) and not isinstance(wander, bool) \
        and math.isfinite(wander) and wander > dev.NORMALISE_ABOVE_DB
    return PulseAnalyzer(cfg, ref, static)


class WarmStart:
    """Aligned pulses in, per-pulse rows out: holds the pulses until the static estimate
    can be primed from the first ``analysis.static_window_s`` of valid pulses, then runs
    the :class:`PulseAnalyzer` on them and on all that follow. The daemon's warm-up and
    the offline analysis of a file are this same code."""

    def __init__(self, cfg: Config, ref: Reference, *, rows: bool = False,
                 uncertain_gaps: bool = False, by_number: bool = False) -> None:
        self.cfg, self.ref, self.rows = cfg, ref, rows
        self.uncertain_gaps = uncertain_gaps
        self.by_number = by_number      # the daemon's cadence (PulseAnalyzer.by_number)
        self.warmup = int(max(round(cfg.analysis.static_window_s * cfg.prf_hz), 1))
        self.analyzer: PulseAnalyzer | None = None
        self._held: list[AlignedPulses] = []
        self.held_valid = 0

    def push(self, got: AlignedPulses) -> list[dict[str, Any]]:
        """One block of aligned pulses; rows (with ``rows``) of the pulses analysed now."""
        if self.analyzer is not None:
            return self.analyzer.process(got, rows=self.rows) if len(got) else []
        if len(got):
            self._held.append(got)
            self.held_valid += int(got.valid.sum())
        return self._start() if self.held_valid >= self.warmup else []

    def finish(self, min_pulses: int) -> list[dict[str, Any]]:
        """At the end of a recording shorter than the warm-up: prime from all it holds,
        if that is at least ``min_pulses``."""
        if self.analyzer is None and self.held_valid >= min_pulses:
            return self._start()
        return []

    def _start(self) -> list[dict[str, Any]]:
        first = np.concatenate([h.pulses[h.valid] for h in self._held])[:self.warmup]
        if len(first) > 8:
            # bursts of interference must not prime the static estimate
            res = first - median(first, axis=0)
            first = first[~dev.burst_mask(median(res * res, axis=1))]
        self.analyzer = new_analyzer(self.cfg, self.ref, first)
        self.analyzer.uncertain_gaps = self.uncertain_gaps
        self.analyzer.by_number = self.by_number
        rows: list[dict[str, Any]] = []
        for h in self._held:
            rows.extend(self.analyzer.process(h, rows=self.rows))
        self._held = []
        return rows


def device_figures(aligner: PulseAligner, an: PulseAnalyzer | None) -> dict[str, Any]:
    """What an analysis saw of the device (analyze's summary, the daemon's stats): the
    share of direct couplings that were clipped, the gain's wander, the pulses skipped
    for bursts, and the room's tail as the reference measured it."""
    dv = an.ref.meta.get("device") if an is not None else None
    dv = dv if isinstance(dv, dict) else {}
    return {
        "clipped_coupling": round(aligner.coupling_clipped / max(aligner.edges_measured, 1),
                                  4),
        "gain_wander_db": round(an.static.gain_wander_db, 2) if an is not None else None,
        "burst_pulses": an.bursts.bursts if an is not None else 0,
        "tail_pris": dv.get("tail_pris"),
        "range_scale": round(an.scale, 5) if an is not None else None,
    }

