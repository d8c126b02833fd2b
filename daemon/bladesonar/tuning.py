"""The analysis's tuning constants, in one place, and the settings of its stages built
from the config (the tracker, the decision, the state machine).

None of these is in the config: each was set by hand against the simulator's ground
truth (tests/, tools/bench_day, tools/days.py) or follows from the physics named beside
it; a change is checked the same way. The configurable values live in config.py.
"""

from __future__ import annotations

from .config import Config
from .dsp import aliasing
from .dsp.decide import DecideSettings
from .dsp.tracking import TrackerSettings
from .reference_build import Reference
from .transitions import TransitionSettings

#: Length of the short motion window that calls a fan at rest, seconds.
STILL_WINDOW_S = 1.5
#: The short meter's static estimate is this many times slower than the matches' (3 s):
#: hours. Only change between pulses counts, not a stale estimate, but the estimate's own
#: approach to a fan that has just come to rest is a change: over the meter's 1.5 s it is
#: nearly a straight line, 0.5 % of the difference at 100 (300 s), which at 50 dB SNR
#: stood over the noise and kept every rest of a simulated day from being called stopped
#: (bench_day --snr-db 50). At 10000 it is 40 dB lower.
SLOW_FACTOR = 10000.0
#: Pulses over which the noise estimate of the scene test follows a fall (decide.NoiseFloor;
#: it rises over the analysis window): a quarter second, against the window's 5 s.
NOISE_FALL = 8.0
#: Share of the band (up to Nyquist) the short meter's envelope features keep: the top of
#: the band carries the aligner's fractional-shift error, which looks like motion under
#: clock drift at high SNR (docs/dynamics.md).
STILL_BAND = 0.2
#: Added to the short meter's noise-alone threshold (decide.noise_threshold, its 98th
#: percentile): room for what the device adds to white noise.
NOISE_MARGIN = 0.03
#: How far the short meter's rest threshold may rise above the noise-alone one on what
#: the device reads at rest (decide.RestFloor), and over how many of those readings
#: (decisions, every 4 pulses: the last 30 s of rest, from 3.5 s on): a turning fan reads
#: 1.43 or more at the 1st percentile in the reverberant room that needed it (1.30 then),
#: 1.67 at the 5th in the tuned room.
REST_SHIFT_MAX = 0.15
REST_KEEP = 256
REST_LEAST = 30
#: The share of the short meter's readings while the fan turns that the rest threshold
#: may come down to (decide.TurningFloor), kept over as many decisions as the rest's
#: (REST_KEEP, REST_LEAST): a stop needs the meter quiet over its confirmation, and a
#: turning fan that reads under the threshold one decision in ten seldom does.
TURNING_QUANTILE = 0.1
#: A short-meter reading this many times the rest threshold, while a rest's hold is on,
#: is the fan moving again (analyzer._let_go_at_start): a start read 3.6-6.7 in its first
#: decisions in the room that needed it (threshold 1.15), a resting fan stays under the
#: threshold but for its first window (REST_SHIFT_MAX lets the threshold rise 0.15).
START_STILL = 2.0

#: The accepted share read against this device's settled tracks (dsp/decide.AcceptFloor):
#: settled means older than the window and this many standard deviations clear of zero
#: (the decision's own "clear" test); the typical share never counts as under
#: ACCEPT_LEAST_SHARE (a room where settled tracks accept less than that is not one
#: where a track's share says anything), from ACCEPT_LEAST of the last ACCEPT_KEEP
#: decisions.
ACCEPT_CLEAR_SD = 4.0
ACCEPT_LEAST_SHARE = 0.6
ACCEPT_KEEP = 1024
ACCEPT_LEAST = 64

#: Pulses between checks of a poorly accepted track (PulseAnalyzer._recheck_track).
RECHECK_EVERY = 8

#: Largest difference between the mean rates of a window's two halves, as a share of the
#: window's mean rate, for the window to read as steady (a wobble) rather than a ramp.
TREND_SHARE = 0.02

#: Seconds of a track's clear matches a changing rate is read from (the slope, at the
#: latest pulse, of a quadratic through their phases: PulseAnalyzer.ramp_rate), and the
#: fewest matches it needs. Where matches come in bursts (a slow fan, a blade out of view
#: half its period, low SNR) the follower's rate swings with each burst: on spent
#: held-out rooms at 7.7-12.8 dB its error on ramps was 8 % or more on 26-30 % of the
#: states with no lag in the median. One second is too short to average a burst out;
#: 3 s lags a ramp's knees (docs/dynamics.md, the fiftieth range).
RAMP_FIT_S = 2.0
RAMP_FIT_LEAST = 8

#: Largest difference between a settled fan's steady rate (the window's mean, or the
#: track's) and the latest rate (the follower's), as a share, for the steady one to be
#: reported: the follower's own wander on a steady fan is about 1.4 % at the 95th
#: percentile, the change in the first half second of a 0.1 Hz/s ramp from 0.3 Hz 15 %.
SETTLED_AGREE = 0.03

#: Pulses between the copies of the static estimate kept for a fan that comes to rest,
#: and how many are kept (analyzer.RestHold): 20 s. A spin-down's last moment above three
#: times the floor lies up to 12 s before its stop is confirmed (from 0.2 Hz over the
#: slowest ordinary spin-down, 12 s, 9 s of it slower), and analyze's blocks of 256
#: pulses (7.5 s) have copied the estimate that far ahead of the pulse being decided.
#: At 12 s kept, a rest 8 s after such a moment found no copy old enough and was not held
#: offline (spent held-out 1600018's scene, tests/test_slow_rest_and_start.py).
SNAPSHOT_EVERY = 17
SNAPSHOTS = 40
#: Longest hold of the static estimate while the fan rests, s (RestHold).
HOLD_S = 600.0
#: How long a turning state must have been published before its speed bounds new lines,
#: s (analyzer.RateBound).
ANCHOR_TRUST_S = 2.0
#: How many times its speed a turning state published for less than ANCHOR_TRUST_S may
#: be off (RateBound): the wrong first answer above was 1.8 times too slow.
UNTRUSTED_FACTOR = 2.5

#: Largest range scale (c now / c at the reference) followed by rescaling: beyond it
#: (about 17 degrees C) the reference no longer fits and the answer is unknown.
SCALE_LIMIT = 0.03
#: Least envelope correlation between the reference's static room and now's for the
#: range scale to be trusted (below it the room itself has changed).
SCALE_MIN_CORR = 0.5
#: Pulses between re-estimates of the range scale (the room warms up over hours).
SCALE_EVERY = 1024

#: Acceleration noise of the rate follower: the standard deviation of its change per half
#: second, as a share of the steepest ramp (tracking.max_ramp_hz_s). A quarter first: on
#: simulated ramps of 0.03-0.1 Hz/s at 10 dB the 95th percentile rate error fell from
#: 13 % to 9-11 % (the follower's own rate was less noisy, so the matches favoured it
#: sooner); a lock taken on a ramp still starts with the steepest ramp as uncertainty.
#: 0.4 once matches with no blade in view lost their quality (fingerprint.FLAT_SHARE):
#: the ramp error's 95th percentile in four simulated hours went from 8.7 / 9.1 / 10.4 /
#: 8.1 % to 8.0 / 9.3 / 9.7 / 7.8 % (0.35: 8.3 / 9.2 / 10.0 / 7.8 %; 0.5: a reversal read
#: as a stop and a start, and a 3.2 s stop, in seed 3), every event the same; steady
#: rates a little noisier (all states' 95th percentile 2.4-3.6 %, from 2.2-3.2 %).
#: Before that change 0.35 had cost a 0.94 s 'unknown' mid-turn.
ACCEL_NOISE = 0.4
#: Longest a track coasts through weak matches (s; dsp.tracking.Tracker._coasts): a slow
#: fan's blind half-period, 1.1 s at 0.15 Hz in the paper room, with room to spare.
COAST_MAX_S = 2.0
#: The slowest track that coasts, in multiples of tracking.rate_floor_hz
#: (dsp.tracking.Tracker._coasts). One floor, not two (the rate a new direction needs):
#: a start's first slow tracks must coast too (docs/dynamics.md, "Why each rule is
#: there").
COAST_MIN_FLOORS = 1.0


def tracker_settings(cfg: Config, ref: Reference) -> TrackerSettings:
    """Tracker tuning from the config, with the slew bound from the reference's rate."""
    t = cfg.tracking
    max_rate = min(t.slew_limit * ref.cycles_per_pulse, 0.45)
    prf = cfg.prf_hz
    # the steepest ramp, in blade cycles per pulse per pulse; the acceleration's random
    # walk lets a ramp start within about half a second
    max_accel = t.max_ramp_hz_s * cfg.scene.blades / (prf * prf)
    onset = max(0.5 * prf, 1.0)
    return TrackerSettings(max_rate=max_rate, q_rate=t.rate_noise ** 2,
                           meas_sigma=t.meas_sigma, gate_sigma=t.gate_sigma,
                           reacquire_after=t.reacquire_after, init_pulses=t.init_pulses,
                           min_coherence=t.min_coherence,
                           q_accel=(max_accel * ACCEL_NOISE) ** 2 / onset,
                           max_accel=max_accel, coast_max=int(round(COAST_MAX_S * prf)),
                           coast_min_rate=COAST_MIN_FLOORS * t.rate_floor_hz
                           * cfg.scene.blades / prf)


def decide_settings(cfg: Config) -> DecideSettings:
    t = cfg.tracking
    return DecideSettings(motion_threshold=t.motion_threshold, min_confidence=t.min_confidence,
                          slew_limit=t.slew_limit, alias_margin=aliasing.MARGIN,
                          rate_floor_hz=t.rate_floor_hz)


def transition_settings(cfg: Config) -> TransitionSettings:
    t = cfg.tracking
    return TransitionSettings(rate_floor_hz=t.rate_floor_hz, confirm_s=t.confirm_s,
                              max_reversal_hz_s=t.max_reversal_hz_s,
                              blind_turn_rev=0.5 / cfg.scene.blades,
                              still_window_s=STILL_WINDOW_S)

