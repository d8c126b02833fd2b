"""Clipped couplings, reverberation build-up, bursts, gain wander and range scaling, on
signals whose answer is known in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bladesonar import config
from bladesonar.dsp import device as dev
from bladesonar.dsp import pulses, rangescale
from bladesonar.dsp.gate import Gate
from bladesonar.dsp.pulses import CLIPPED, OK, AlignedPulses, PulseAligner, RecordingCheck, align
from bladesonar.errors import InputError
from bladesonar.reference_build import build_reference
from synth_pulses import add_pulse, pulse_train

PRI = 1297
FS = 44100.0
FULL = 32767.0 / 32768.0


def _ring(x: np.ndarray, at: float, amp: float) -> None:
    """A ringing coupling (a small speaker): decaying band-limited impulses."""
    for j in range(12):
        add_pulse(x, at + 8.7 * j, amp * (-0.7) ** j)


def _clipped_ringing_edges(n: int, over: float, drift: float, noise: float
                           ) -> tuple[PulseAligner, np.ndarray]:
    """n pulses of a ringing coupling ``over`` times full scale, clipped, aligned: (the
    aligner, the edge errors against the truth once settled, from pulse 40); every pulse
    but the first and last must be usable."""
    x, edges, _ = pulse_train(n, PRI, rate=0.05, drift_ppm=drift, noise=noise, direct=0.0)
    for e in edges:
        _ring(x, e, over)
    x = np.clip(x, -FULL, FULL)
    a = PulseAligner(PRI, Gate(0, PRI - 24, FS, 343.0))
    got = AlignedPulses.concat([a.push(x), a.flush()], PRI - 24)
    keep = got.index < n
    assert (got.status[keep] == OK)[1:-1].all(), got.status
    return a, (got.edges[keep] - edges[got.index[keep]])[40:]


@pytest.mark.parametrize("over, drift", [(4.0, 80.0), (8.0, -100.0), (40.0, 0.0),
                                         (8.0, 0.0)])
def test_clipped_coupling_is_timed_and_its_pulses_kept(over, drift):
    """A ringing, full-band coupling `over` times full scale, clipped: every pulse stays
    usable and the edges keep their spacing: exactly the PRI with a shared clock (any
    overdrive), the drifted PRI within a few hundredths of a sample under 100 ppm of
    drift up to 18 dB of overdrive (documented limit; a constant offset is only a range
    offset)."""
    n = 120
    a, settled = _clipped_ringing_edges(n, over, drift, noise=1e-4)
    assert a.coupling_clipped >= n - 4
    assert np.ptp(settled) < (1e-3 if drift == 0 else 0.35)   # one line
    assert abs(a.period - PRI * (1 + drift * 1e-6)) < (1e-4 if drift == 0 else 0.03)
    # clipping inside the coupling is not held against a pulse: beyond it, it is
    assert 20 <= a.coupling_zone <= 140


@pytest.mark.parametrize("over, drift", [(4.0, 40.0), (8.0, -100.0), (4.0, 10.0)])
def test_clipped_coupling_is_timed_by_its_ringing_at_high_snr(over, drift):
    """A quiet recording, the coupling clipped, the clocks drifting: the settled edges lie
    on the truth's line within 2e-3 sample. Timed by the plateaus' edges they were off by
    a function of the sub-sample position (0.05-0.19 sample rms here, 0.11 on the
    simulator's small speaker), a change between pulses that kept a fan at rest at
    40-60 dB from being called stopped; the unclipped ringing times it as a band-limited
    peak is timed."""
    _, err = _clipped_ringing_edges(200, over, drift, noise=1e-6)
    assert np.max(np.abs(err - np.mean(err))) < 2e-3


def _coarse_clipped(n: int, drift: float, lose_at: int | tuple[int, int] | None = None,
                    whole: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n pulses of a coupling with no ringing (an ideal speaker) 4 times full scale,
    clipped: timed from its plateaus' edges only. ``lose_at``: samples lost in
    that pulse's gate (``lose_at`` alone: one; a pair (pulse, samples)); ``whole``: the
    whole recording at once (pulses.align_recording). (the edges found, their pulse
    numbers, the true edges as received)."""
    x, edges, _ = pulse_train(n, PRI, rate=0.05, drift_ppm=drift, noise=1e-4, direct=0.0)
    for e in edges:
        add_pulse(x, e, 4.0)
    x = np.clip(x, -FULL, FULL)
    true = edges.copy()
    if lose_at is not None:
        at, lost = (lose_at, 1) if isinstance(lose_at, int) else lose_at
        cut = int(edges[at]) + 600
        x = np.delete(x, np.arange(cut, cut + lost))
        true[at + 1:] -= float(lost)
    g = Gate(0, PRI - 24, FS, 343.0)
    got = pulses.align_recording(x, PRI, g)[0] if whole else align(x, PRI, g)
    keep = got.index < n
    return got.edges[keep], got.index[keep], true


@pytest.mark.parametrize("drift", [20.0, -60.0])
def test_a_coarsely_timed_clipped_coupling_keeps_to_the_clocks_line(drift):
    """Timed from its plateaus' edges, a clipped coupling's edge is off by a function of
    the sub-sample position, which drift sweeps through every 1 / (drift x PRI) pulses
    (39 at 20 ppm). The schedule loop keeps the edges on the clocks' line within 0.02
    sample once settled (a loop with a memory of 6 pulses followed that error: 0.1
    sample, a slow change of the whole gate that a fan at rest showed as motion)."""
    edges, index, true = _coarse_clipped(700, drift)
    err = edges - true[index]
    settled = err[index >= 450]
    assert np.max(np.abs(settled - np.mean(settled))) < 0.02, np.ptp(settled)


@pytest.mark.slow
@pytest.mark.parametrize("drift, n", [(10.0, 3000), (2.5, 5000)])
def test_a_coarsely_timed_coupling_under_slow_drift_has_its_bias_taken_out(drift, n):
    """At 10 ppm the sub-sample position turns once every 77 pulses, slower than the
    schedule loop averages: timed from its plateaus' edges (off by a sawtooth of the
    position) the edges followed that error, 0.04 sample off the clocks' line. Learned
    per position against a line of long memory and taken out (dsp/pulses._FractionBias),
    the settled edges lie within 0.015 of it. At 2.5 ppm a turn takes 308 pulses: the
    learner's line, younger than a turn, leaned along the error and took it for a jump
    once a turn, and started again each time: 0.7 sample peak to peak, never learned
    (a held-out room's clipped coupling at 1.8 ppm: its fan at rest read as moving)."""
    edges, index, true = _coarse_clipped(n, drift)
    err = edges - true[index]
    settled = err[index >= n - 500]
    assert np.max(np.abs(settled - np.mean(settled))) < 0.015, np.ptp(settled)


@pytest.mark.parametrize("drift, lose_at", [(-13.6, None), (60.0, None), (-140.0, (300, 37))])
def test_a_whole_recording_takes_the_plateau_timings_error_out_from_its_first_pulse(
        drift, lose_at):
    """A reference is learned from 20 s, about 680 pulses: fewer than the streaming
    learner needs (a thousand) before it trusts its line, so its edges followed the
    plateau timing's sawtooth (0.2 sample rms at -13.6 ppm, a turn every 57 pulses), the
    strong static echoes turned with it, and a held-out room's reference was learned at
    that turn instead of the fan. Over the whole recording the line and the error are
    fitted together (dsp/pulses.fit_fraction_bias): every edge lies on the clocks' line
    within 0.01 sample from the first pulse on, across 37 lost samples too."""
    n = 680
    edges, index, true = _coarse_clipped(n, drift, lose_at=lose_at, whole=True)
    err = edges - true[index]
    assert np.max(np.abs(err - np.median(err))) < 0.01, np.ptp(err)
    streamed, index, true = _coarse_clipped(n, drift, lose_at=lose_at)
    err = streamed - true[index]
    assert np.max(np.abs(err - np.median(err))) > 0.05   # what the stream alone gives


def test_a_whole_recording_without_drift_is_left_as_streamed():
    """With one clock exactly the sub-sample position never turns: the plateau timing's
    error is one constant (a range offset), nothing to fit, and the recording is aligned
    as the stream aligns it."""
    whole, i1, _ = _coarse_clipped(300, 0.0, whole=True)
    streamed, i2, _ = _coarse_clipped(300, 0.0)
    assert np.array_equal(i1, i2) and np.array_equal(whole, streamed)


def test_a_clipped_coupling_follows_a_lost_sample():
    """One sample lost inside pulse 500: the edges after it are a sample earlier. The
    loop, settled to its long memory, moves there at once (within the coarse timing's
    own error, 0.2 sample) and, averaging the measurements since, is back on the clocks'
    line within 0.03 after 100 pulses, the PRI kept."""
    edges, index, true = _coarse_clipped(660, 20.0, lose_at=500)
    err = edges - true[index]
    line = np.mean(err[(index >= 450) & (index < 500)])
    assert np.max(np.abs(err[(index >= 503) & (index < 600)] - line)) < 0.2
    assert np.max(np.abs(err[(index >= 600) & (index < 659)] - line)) < 0.03


@pytest.mark.parametrize("drift", [40.0, -15.0])
def test_a_coupling_that_clips_at_some_positions_only_keeps_to_the_clocks_line(drift):
    """A full-band coupling 1.3 times full scale clips when its peak falls near a sample
    and not half a sample off (0.64 of its height there), where it is acquired: drift
    then sweeps it across the grid, and every 1 / (drift x PRI) pulses it clips. The
    peak fit reads a clipped top off by up to 0.04 sample, a change of the whole gate
    that a fan at rest in a random scene's room showed as motion (its short meter 1.5-2.2
    against 1.15). Once settled the edges lie within 5e-3 sample of the clocks' line, and
    every pulse is kept."""
    n = 700
    x, edges, _ = pulse_train(n, PRI, rate=0.05, drift_ppm=drift, noise=1e-6,
                              direct=1.3, first_edge=377.5)
    x = np.clip(x, -FULL, FULL)
    a = PulseAligner(PRI, Gate(0, PRI - 24, FS, 343.0))
    got = AlignedPulses.concat([a.push(x), a.flush()], PRI - 24)
    keep = got.index < n
    assert (got.status[keep] == OK)[1:-1].all(), got.status
    err = (got.edges[keep] - edges[got.index[keep]])[got.index[keep] >= 400]
    assert np.max(np.abs(err - np.mean(err))) < 5e-3, np.ptp(err)
    assert a.coupling_clipped >= 10                   # it did clip, at some positions


@pytest.mark.parametrize("ringing", [True, False])
def test_only_a_ringing_tail_times_a_clipped_coupling(ringing):
    """The tail fit reads a known sub-sample delay off a ringing coupling (0.37 sample,
    to 1e-3), and declines one with no ringing (an ideal speaker: past the plateau only
    noise, whose best shift is anywhere in the grid), which its plateau's edges time."""
    rng = np.random.default_rng(4)

    def coupling(at: float) -> np.ndarray:
        x = np.zeros(160)
        if ringing:
            _ring(x, at, 4.0)
        else:
            add_pulse(x, at, 4.0)
        return np.clip(x + 1e-3 * rng.standard_normal(len(x)), -FULL, FULL)

    first, later = coupling(30.0), coupling(30.37)
    tail = pulses._tail_shifts(first, FULL)
    assert tail is not None
    d = pulses._tail_offset(tail, later, FULL)
    if ringing:
        assert d is not None and abs(d - 0.37) < 1e-3
    else:
        assert d is None


def test_clipping_past_the_coupling_still_marks_the_pulse():
    x, edges, _ = pulse_train(80, PRI, rate=0.05, noise=1e-4, direct=0.0)
    for e in edges:
        _ring(x, e, 10.0)
    x[int(edges[30]) + 600] = 5.0                              # an overload in the gate
    x = np.clip(x, -FULL, FULL)
    got = align(x, PRI, Gate(0, PRI - 24, FS, 343.0))
    assert got.status[30] == CLIPPED and (got.status[31:60] == OK).all()


def test_recurring_coupling_clipping_is_not_an_overload():
    chk = RecordingCheck(pri=PRI, min_pulses=64)
    x, edges, _ = pulse_train(100, PRI, rate=0.05, noise=1e-4, direct=0.0)
    for e in edges:
        _ring(x, e, 40.0)
    x = np.clip(x, -FULL, FULL)
    chk.update(x)
    assert chk.clipped / chk.n > 0.01                          # over the 1 % limit...
    assert chk.overload_clipped == 0 and chk.coupling_clipped == chk.clipped
    assert chk.finish() == []                                  # ...and not refused
    noisy = np.clip(x + 0.5 * np.random.default_rng(0).standard_normal(len(x)), -FULL, FULL)
    chk2 = RecordingCheck(pri=PRI, min_pulses=64)
    chk2.update(noisy)
    assert chk2.overload_clipped > 0.01 * chk2.n               # clipping everywhere is


def test_buildup_gives_the_rt60_of_a_tail_of_known_decay():
    """Window k holds the tails of pulses 0..k: its shortfall from the steady window
    shrinks by q per PRI; q = 10^(-6 PRI / (RT60 fs))."""
    rng = np.random.default_rng(1)
    L, rt = 800, 0.6
    q_amp = 10 ** (-3.0 * PRI / (rt * FS))                    # amplitude per PRI
    lags = 80
    segs = [rng.standard_normal(L) * q_amp ** j for j in range(lags)]   # T_j
    steady = np.sum(segs, axis=0)
    rows = np.array([np.sum(segs[:k + 1], axis=0) for k in range(300)])
    rows += 0.01 * rng.standard_normal(rows.shape)
    rt60, n = dev.tail_from_buildup(rows, steady, PRI, FS)
    assert abs(rt60 - rt) < 0.15 * rt and n >= 8
    dry = np.tile(steady, (300, 1)) + 0.01 * rng.standard_normal((300, L))
    assert dev.tail_from_buildup(dry, steady, PRI, FS) == (0.0, 0)


def test_burst_gate_skips_bursts_and_keeps_its_bar():
    g = dev.BurstGate()
    rng = np.random.default_rng(2)
    level = 1.0 + 0.2 * rng.random(300)
    level[100:130] = 50.0                                      # a burst of 30 pulses
    flags = np.array([g(float(e)) for e in level])
    assert flags[100:130].all() and not flags[:100].any() and not flags[130:].any()
    assert g.bursts == 30
    m = dev.burst_mask(level)
    assert m.sum() == 30


def test_burst_gate_takes_a_lasting_step_as_a_new_level():
    """A step up of the residual's level that lasts (x20, as a fan coming to rest where
    the static estimate had not seen its blade, at 30 dB SNR: spent held-out 800006) is
    skipped for BURST_LONGEST pulses and then learned as the new level: the pulses after
    it are analysed. On the old gate every pulse after the step was a burst, for the
    rest of the day. A real burst, shorter, is still skipped whole, and so is one on the
    new level."""
    g = dev.BurstGate()
    rng = np.random.default_rng(4)
    level = 1.0 + 0.2 * rng.random(600)
    level[200:] *= 20.0
    level[450:480] = 1000.0                                    # a burst on the new level
    flags = np.array([g(float(e)) for e in level])
    assert not flags[:200].any()
    assert flags[200:200 + dev.BURST_LONGEST - 1].all()
    assert not flags[200 + dev.BURST_LONGEST - 1:450].any()
    assert flags[450:480].all() and not flags[480:].any()
    assert g.relevels == 1 and g.bursts == dev.BURST_LONGEST - 1 + 30


def test_gain_wander_of_a_known_agc():
    prf = FS / PRI
    t = np.arange(2000) / prf
    g = 10 ** (2.0 * np.sin(2 * np.pi * t / 10.0) / 20)       # +-2 dB
    assert abs(dev.gain_wander_db(g, prf) - 4.0) < 0.2
    assert dev.gain_wander_db(np.ones(2000), prf) == 0.0


@pytest.mark.parametrize("s", [0.985, 1.0, 1.012, 1.026])
def test_range_scale_of_a_stretched_room(s):
    """Echoes at delays d in the reference come at d / s now."""
    L, start = 780, 490
    ref, now = np.zeros(L), np.zeros(L)
    rng = np.random.default_rng(3)
    delays, amps = rng.uniform(start + 20, start + L - 60, 25), rng.uniform(0.2, 1, 25)
    for d, a in zip(delays, amps, strict=True):
        add_pulse(ref, d - start, a)
        add_pulse(now, d / s - start, a)
    est, corr = rangescale.estimate_scale(ref, now, start)
    assert abs(est - s) < 5e-4 and corr > 0.8
    # rescaled features line up with the reference's again
    r = rangescale.Rescaler(est, start, L)
    fr = rangescale.envelope(ref)[None, :]
    fn = r(rangescale.envelope(now)[None, :])
    c = float(fr[0] @ fn[0]) / math.sqrt(float(fr[0] @ fr[0]) * float(fn[0] @ fn[0]))
    assert c > 0.9


def test_a_reference_whose_echoes_clip_in_every_pulse_asks_for_less_volume():
    """An echo close to the device that clips in every pulse leaves too few pulses to
    use: the refusal names the clipping and the volume (what a user can change), not
    drop-outs (a random room, its sensor 0.32 m from a wall returning 0.86, said "fix
    the drop-outs (621 pulses dropped)")."""
    x, edges, _ = pulse_train(200, PRI, rate=0.05, noise=1e-4, direct=0.0)
    for e in edges:
        _ring(x, e, 10.0)
        x[int(e) + 600] = 5.0                                  # overloads in every pulse
    x = np.clip(x, -FULL, FULL)
    cfg = config.replace(config.Config(), waveform={"pri_samples": PRI})
    with pytest.raises(InputError, match="lower the playback volume") as e:
        build_reference(x, cfg)
    assert "drop-outs" not in str(e.value)


def test_a_coupling_that_starts_clipping_under_drift_keeps_its_pulses():
    """A coupling acquired unclipped (its peak between two samples) clips later, when
    clock drift brings the peak onto a sample: that is the coupling, not an echo, and
    its pulses stay usable (a random room, no nuisance, coupling 1.25 of full scale:
    479 of 679 reference pulses were left out as clipped, and its day was `unknown` 79 %
    of the time). An overload further in still marks its pulse."""
    x, edges, _ = pulse_train(200, PRI, rate=0.05, noise=1e-4, direct=1.15,
                              first_edge=100.5, drift_ppm=40.0)
    x[int(edges[150]) + 600] = 5.0
    x = np.clip(x, -FULL, FULL)
    assert (np.abs(x[np.round(edges).astype(int)]) >= FULL).sum() > 20   # it clips
    got = align(x, PRI, Gate(0, PRI - 24, FS, 343.0))
    ok = got.status == OK
    assert got.status[150] == CLIPPED
    assert ok.sum() >= len(got) - 4, np.unique(got.status, return_counts=True)  # (the end)
    err = got.edges[ok] - edges[got.index[ok]]
    assert np.sqrt(np.mean(err ** 2)) < 0.1, np.sqrt(np.mean(err ** 2))
