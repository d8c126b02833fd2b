"""Rate aliases near p/q cycles per pulse: which rates count as commensurate, and the line
fit against the table that tells an alias from the true rate (synthetic tables, known rate)."""

from __future__ import annotations

from fractions import Fraction
from typing import Any

import numpy as np
import pytest

from bladesonar.dsp import aliasing
from bladesonar.dsp.decide import decide
from bladesonar.dsp.fingerprint import match

FS, PRI, K = 44100, 1297, 4          # the default config: PRF 34.0 Hz, 4 blades
B, L = 40, 64


def _cpp(rate_hz: float) -> float:
    """Blade periods per pulse of a fan turning at ``rate_hz``."""
    return K * rate_hz * PRI / FS


def test_which_rates_are_commensurate():
    # 0.5 Hz is 0.05882 blade period per pulse, 2.6e-6 from 1/17: over a 5 s window
    # (170 pulses) the pulses see 17 angles
    assert aliasing.near_fraction(_cpp(0.5), span=170) == Fraction(1, 17)
    # 0.45 Hz (0.05294) is 3e-4 from 1/19: the angles drift through the gaps
    assert aliasing.near_fraction(_cpp(0.45), span=170) is None
    # the tracked rate's uncertainty widens the test
    assert aliasing.near_fraction(_cpp(0.45), span=170, rate_std=2e-4) == Fraction(1, 19)
    # a track standing still may be the alias of any p/q
    assert aliasing.near_fraction(3e-4, span=170) == 0
    assert aliasing.near_fraction(3e-4, span=170, zero=False) is None
    # a reference of 406 pulses: 1/8 exactly, 1e-5 off (drifts 0.004 < 1/16), 2e-3 off
    assert aliasing.folded_angles(0.125, 406) == Fraction(1, 8)
    assert aliasing.folded_angles(0.125 + 1e-5, 406) == Fraction(1, 8)
    assert aliasing.folded_angles(0.125 + 2e-3, 406) is None
    assert aliasing.folded_angles(float("nan"), 406) is None


def _table(visible: float | None) -> np.ndarray:
    """Echo pattern by blade phase: a bump whose range follows the phase; with
    ``visible`` it is seen only within that distance of phase 0.5 (the paper room's fan
    shows its blades over a narrow range of angles), else at every phase."""
    ph = np.arange(B) / B
    pos = 8.0 + 48.0 * ph
    amp = np.ones(B) if visible is None else np.exp(-((ph - 0.5) / visible) ** 2)
    x = np.arange(L)
    t = amp[:, None] * np.exp(-0.5 * ((x[None, :] - pos[:, None]) / 2.0) ** 2)
    return t - t.mean(axis=1, keepdims=True)


def _pulses(table: np.ndarray, rate: float, n: int = 170, phase0: float = 0.5,
            noise: float = 0.02, seed: int = 0):
    from bladesonar.dsp.fingerprint import table_lookup
    k = np.arange(n)
    f = table_lookup(table, phase0 + rate * k)
    return k, f + noise * np.random.default_rng(seed).standard_normal(f.shape)


def test_one_visible_angle_in_five_is_ambiguous_not_a_confident_alias():
    """At 1/5 period per pulse only the angle at 0.5 shows the blade: the matches repeat
    every 5 pulses and circular regression finds +1/5 and -1/5 equally coherent. The line
    fit cannot tell them apart either, and says so."""
    table = _table(visible=0.05)
    k, f = _pulses(table, 0.2)
    m = match(f, table)
    u = m.quality * np.exp(2j * np.pi * m.phase)
    coh = {w: abs(np.sum(u * np.exp(-2j * np.pi * w * k))) / m.quality.sum()
           for w in (0.2, -0.2)}
    assert coh[0.2] > 0.9 and abs(coh[0.2] - coh[-0.2]) < 0.05, coh
    fine = aliasing.fine_table(table)
    for tracked in (0.2, -0.2):
        v = aliasing.check_aliases(f, k, fine, tracked, 1e-4, max_rate=0.45, min_rate=0.01)
        assert v is not None and v.frac.denominator == 5
        assert v.status == "ambiguous" and v.gap < aliasing.MARGIN, v
    # ... and the decision is then unknown, with the reason
    assert v is not None
    d = decide(rate=-0.2, rate_std=1e-4, locked=True, accepted=1.0, quality=0.5, motion=3.0,
               scene=100.0, ref_cycles_per_pulse=0.05, ref_rate_hz=0.5, ref_direction="ccw",
               alias_gap=v.gap, alias_note="rate ambiguous: test")
    assert d.direction == "unknown" and d.reason == "rate ambiguous: test"
    assert not d.direction_doubt        # (its speed is in doubt too: no rate bound on it)
    assert d.confidence < 0.5 and d.relative_rate == pytest.approx(-4.0)


@pytest.mark.parametrize("true_rate", [0.2, -0.125, 1 / 17])
def test_a_visible_pattern_resolves_the_alias(true_rate):
    """When the pattern changes over every angle, the line fit picks the true rate from
    any of its aliases (here from the mirror and from a shifted alias)."""
    table = _table(visible=None)
    k, f = _pulses(table, true_rate)
    fine = aliasing.fine_table(table)
    q = Fraction(true_rate).limit_denominator(24).denominator
    for tracked in (true_rate, -true_rate, true_rate + 2.0 / q):
        if abs(tracked) > 0.45:
            continue
        v = aliasing.check_aliases(f, k, fine, tracked, 1e-4, max_rate=0.45, min_rate=0.01)
        assert v is not None, tracked
        assert v.best_rate == pytest.approx(true_rate, abs=1e-9), (tracked, v)
        assert v.status == ("clear" if tracked == true_rate else "resolved"), (tracked, v)
        assert v.gap >= aliasing.MARGIN
        # the best line's phase at the last pulse is the true one
        want = (0.5 + true_rate * k[-1]) % 1.0
        assert abs((v.best_phase - want + 0.5) % 1.0 - 0.5) < 1.0 / (2 * len(fine[0])) + 1e-9


def test_rates_far_from_small_fractions_are_not_checked():
    table = _table(visible=None)
    k, f = _pulses(table, 0.0529)                # the 3-D sample's rate: not near p/q
    v = aliasing.check_aliases(f, k, aliasing.fine_table(table), 0.0529, 0.0,
                               max_rate=0.45, min_rate=0.01)
    assert v is None
    # too short a window to tell
    v = aliasing.check_aliases(f[:10], k[:10], aliasing.fine_table(table), 0.2, 0.0,
                               max_rate=0.45, min_rate=0.01)
    assert v is None


def test_a_trusted_rate_keeps_its_answer_and_the_note_becomes_a_warning():
    common: dict[str, Any] = dict(rate=-0.2, rate_std=1e-3, locked=True, accepted=1.0, quality=0.5,
                  motion=3.0, scene=100.0, ref_cycles_per_pulse=0.05, ref_rate_hz=0.5,
                  ref_direction="ccw")
    plain = decide(**common)
    d = decide(**common, alias_gap=0.4, alias_note="moved off an alias")
    assert (d.direction, d.rotation, d.confidence) == ("reversed", "cw", plain.confidence)
    assert d.warnings == ("moved off an alias",) and not plain.warnings


# ---- the mirror check: a track's path against its mirror image (flat fans' direct echo
# is the same turned either way; only an asymmetric pattern tells the directions apart)

def _symmetric_table() -> np.ndarray:
    """A pattern that is its own mirror image about phase 0.5 (``T(p) = T(1 - p)``): what
    the direct echo of a flat fan gives with no wall echo to break the symmetry."""
    ph = np.arange(B) / B
    pos = 8.0 + 96.0 * np.minimum(ph, 1.0 - ph)
    x = np.arange(L)
    t = np.exp(-0.5 * ((x[None, :] - pos[:, None]) / 2.0) ** 2)
    return t - t.mean(axis=1, keepdims=True)


def _path(rate: float, accel: float, n: int = 170, phase0: float = 0.3) -> np.ndarray:
    k = np.arange(n)
    return phase0 + rate * k + 0.5 * accel * k * k


@pytest.mark.parametrize("accel", [0.0, 2e-4])
def test_the_mirror_of_a_path_fits_an_asymmetric_pattern_worse(accel):
    """Pulses along a path (a steady rate, and a ramp): the true path beats its mirror by
    far more than MIRROR_Z on every noise draw, and a track on the mirror path sees the
    same evidence with the opposite sign (its mirror is the true path)."""
    from bladesonar.dsp.fingerprint import table_lookup
    table = _table(visible=None)
    fine = aliasing.fine_table(table)
    p = _path(0.03, accel)
    for seed in range(10):
        f = table_lookup(table, p)
        f = f + 0.05 * np.random.default_rng(seed).standard_normal(f.shape)
        d = aliasing.distances(f, fine)
        ev = aliasing.mirror_evidence(d, p % 1.0, fine)
        z, sweep = ev.z, ev.sweep
        assert z > aliasing.MIRROR_Z and sweep == pytest.approx(
            abs(p[-1] - p[0]), rel=1e-6), (seed, z)
        z_m = aliasing.mirror_evidence(d, (0.7 - p) % 1.0, fine).z
        assert z_m < -aliasing.MIRROR_Z, (seed, z_m)


def test_a_symmetric_pattern_leaves_the_direction_to_chance():
    """On a pattern that is its own mirror image the evidence is a t statistic of pure
    noise: beyond MIRROR_Z (a confident direction) in few draws of 40, either sign."""
    from bladesonar.dsp.fingerprint import table_lookup
    table = _symmetric_table()
    fine = aliasing.fine_table(table)
    p = _path(0.03, 0.0)
    z_list = []
    for seed in range(40):
        f = table_lookup(table, p)
        f = f + 0.05 * np.random.default_rng(seed).standard_normal(f.shape)
        z_list.append(aliasing.mirror_evidence(aliasing.distances(f, fine), p % 1.0, fine).z)
    zs = np.array(z_list)
    assert np.mean(np.abs(zs) >= aliasing.MIRROR_Z) <= 0.1, zs
    assert np.mean(np.abs(zs) < aliasing.MIRROR_DOUBT_Z) >= 0.8, zs


def _watch_on(table: np.ndarray, rate: float, *, mirror: bool, seed: int = 0,
              n: int = 340, watch: aliasing.AliasWatch | None = None, k0: int = 0,
              seen: list[tuple[int, bool]] | None = None, resting: bool = False
              ) -> tuple[aliasing.AliasWatch, Any]:
    """The alias watch as the analysis runs it, beside a track that follows the line of
    pulses at ``rate`` or (``mirror``) its mirror image, as a track that locked on the
    mirror does. The track is scripted (a real Tracker whose line is set, not fitted):
    what is under test is the watch's verdict on a given line. ``seen`` gets, after each
    pulse, the track's moves so far and whether its line is cleared."""
    from bladesonar.dsp.fingerprint import table_lookup
    from bladesonar.dsp.tracking import Tracker, TrackerSettings
    fine = aliasing.fine_table(table)
    if watch is None:
        watch = aliasing.AliasWatch(fine, 170, 0.03, min_rate=0.003)
    tr = Tracker(TrackerSettings(max_rate=0.45))
    k = np.arange(n)
    f = table_lookup(table, 0.3 + rate * k)
    f = f + 0.05 * np.random.default_rng(seed).standard_normal(f.shape)
    dist = aliasing.distances(f, fine)
    sign = -1.0 if mirror else 1.0
    tr.start_k = tr.locked_k = k0
    tr.P = np.diag([1e-4, 1e-8])
    for i in range(n):
        if tr.relocks == 0:
            tr.x = np.array([(sign * (0.3 + rate * i) + (0.2 if mirror else 0.0)) % 1.0,
                             sign * rate])
        else:                                   # moved by the watch: it runs on the line
            assert tr.x is not None and tr.last_k is not None
            tr.x = np.array([(tr.x[0] + tr.x[1] * (k0 + i - tr.last_k)) % 1.0, tr.x[1]])
        tr.last_k = k0 + i
        watch.push(k0 + i, dist[i], float(tr.x[0]))
        watch.check(tr, accel=0.0, moving=lambda: True, resting=resting)
        if seen is not None:
            seen.append((tr.relocks, watch.mirror_checked(tr) and not watch.mirror_note))
    return watch, tr


def test_a_track_on_the_mirror_line_is_moved_back():
    watch, tr = _watch_on(_table(visible=None), 0.03, mirror=True)
    assert watch.mirror_moves == 1 and tr.x is not None
    assert float(tr.x[1]) == pytest.approx(0.03, rel=0.05)
    assert watch.mirror_note == ""


def test_a_symmetric_room_puts_the_direction_in_doubt_and_new_tracks_wait():
    """No wall echo to tell the directions apart: after half a window the track's
    direction is in doubt (the answer is then unknown, with the reason), and a new track
    in that room starts 'to be confirmed' until its own check clears it."""
    doubted = 0
    for seed in range(6):
        watch, _ = _watch_on(_symmetric_table(), 0.03, mirror=False, seed=seed)
        doubted += bool(watch.mirror_note) and watch.mirror_doubt >= 0.1
    assert doubted >= 5
    d = decide(rate=0.03, rate_std=1e-4, locked=True, accepted=1.0, quality=0.5,
               motion=3.0, scene=100.0, ref_cycles_per_pulse=0.03, ref_rate_hz=0.5,
               ref_direction="ccw", direction_note=watch.mirror_note,
               awaiting_check=watch.awaiting_check)
    assert d.direction == "unknown" and d.reason.startswith("direction in doubt")
    assert d.direction_doubt            # (the speed is known: the rate bound anchors on it)
    # the same watch, a new track in an asymmetric pattern: held at first, then cleared
    watch, _ = _watch_on(_table(visible=None), 0.03, mirror=False, n=8, watch=watch,
                         k0=10 ** 4)
    assert watch.mirror_note.startswith("direction to be confirmed")
    watch, _ = _watch_on(_table(visible=None), 0.03, mirror=False, n=60, watch=watch,
                         k0=2 * 10 ** 4)
    assert watch.mirror_note == ""


def test_a_start_from_rest_in_a_doubtful_room_waits_for_its_own_check():
    """A start's first answers come while the rest's static estimate is still held, when
    the analysis tells the watch the fan rests. In a room where directions have been in
    doubt the new track is 'to be confirmed' then too (the old code cleared every note at
    rest, and spent held-out 1700009 answered three starts the wrong way at once), and
    the answer still says the fan turns, so that the rest's estimate is let go and the
    track's own check can run. In a room never in doubt nothing waits."""
    watch = next(w for w, _ in (_watch_on(_symmetric_table(), 0.03, mirror=False, seed=s)
                                for s in range(6)) if w.doubtful)
    watch, _ = _watch_on(_table(visible=None), 0.03, mirror=False, n=4, watch=watch,
                         k0=10 ** 4, resting=True)
    assert watch.mirror_note.startswith("direction to be confirmed")
    d = decide(rate=0.03, rate_std=1e-4, locked=True, accepted=1.0, quality=0.5,
               motion=3.0, scene=100.0, ref_cycles_per_pulse=0.03, ref_rate_hz=0.5,
               ref_direction="ccw", direction_note=watch.mirror_note,
               awaiting_check=watch.awaiting_check,
               at_rest=True)
    assert d.direction == "unknown" and d.turning and d.direction_doubt
    # the same track once it moves on: its own check clears it
    watch, _ = _watch_on(_table(visible=None), 0.03, mirror=False, n=60, watch=watch,
                         k0=10 ** 4 + 4)
    assert watch.mirror_note == ""
    fresh, _ = _watch_on(_table(visible=None), 0.03, mirror=False, n=4, resting=True)
    assert not fresh.doubtful and fresh.mirror_note == ""


def test_a_steady_runs_windows_add_up_where_one_window_is_too_weak():
    """Wall echoes so weak that one window's evidence on the true line is about its noise
    (t 1.2 on average, under MIRROR_DOUBT_Z in most windows): the whole windows of a
    steady run that share no pulse add up (Stouffer), and after a few the direction is
    cleared and stays so. A track on the mirror line pools the same evidence with the
    opposite sign: it is never cleared while it stays there."""
    table = _symmetric_table() + 0.005 * _table(visible=None)
    n = 170 * 16
    for seed in range(4):
        seen: list[tuple[int, bool]] = []
        _watch_on(table, 0.03, mirror=False, seed=seed, n=n, seen=seen)
        late = [ok for _, ok in seen[-6 * 170:]]
        assert np.mean(late) >= 0.9, (seed, np.mean(late))
        seen = []
        _watch_on(table, 0.03, mirror=True, seed=seed, n=n, seen=seen)
        assert not any(ok for moves, ok in seen if moves == 0), seed


def test_a_runs_pooled_evidence_against_its_track_moves_it_to_the_mirror():
    """Wall echoes so weak that one window seldom reads MIRROR_Z against a track on the
    mirror line: the run's pooled windows do, and they move it as two such windows
    would (the old code left 7 of these 16 tracks on the mirror line for 16 windows;
    spent held-out 1800002 published the mirror for 12 s while its path read -0.7 to
    -2.9 and its fitted line pooled -6.3). A track on the true line in the same rooms,
    and in a room whose echoes are their own mirror image, is never moved."""
    n = 170 * 16
    for scale in (0.005, 0.003):
        table = _symmetric_table() + scale * _table(visible=None)
        for seed in range(8):
            watch, tr = _watch_on(table, 0.03, mirror=True, seed=seed, n=n)
            assert watch.mirror_moves == 1 and tr.x is not None, (scale, seed)
            assert float(tr.x[1]) == pytest.approx(0.03, rel=0.05), (scale, seed)
    for scale in (0.005, 0.0):
        table = _symmetric_table() + scale * _table(visible=None)
        for seed in range(8):
            watch, _ = _watch_on(table, 0.03, mirror=False, seed=seed, n=n)
            assert watch.mirror_moves == 0, (scale, seed)


def test_the_mirror_evidence_of_six_batch_means_is_read_on_the_normal_scale():
    """A 5 s window holds about six blade-period batch means, and their t has five degrees
    of freedom: t 3 is one window in 70 on noise alone (Student's t table: the 0.99
    quantile at 5 degrees is 3.365), which is not MIRROR_Z's significance. Read as the
    normal z of the same tail it is under MIRROR_Z; with many batches a t is a z."""
    ev = aliasing.MirrorEvidence(3.0, 5.0, 0.0, 5)
    assert ev.z < aliasing.MIRROR_Z
    assert aliasing.MirrorEvidence(3.364930, 5.0, 0.0, 5).z == pytest.approx(2.326348, abs=1e-5)
    assert aliasing.MirrorEvidence(-3.364930, 5.0, 0.0, 5).z == pytest.approx(-2.326348,
                                                                             abs=1e-5)
    assert aliasing.MirrorEvidence(3.0, 5.0, 0.0, 10 ** 6).z == pytest.approx(3.0, abs=1e-3)
    # a window at 0.03 blade cycles per pulse (5.1 cycles in 170 pulses): six batches
    from bladesonar.dsp.fingerprint import table_lookup
    table = _table(visible=None)
    fine = aliasing.fine_table(table)
    p = _path(0.03, 0.0)
    f = table_lookup(table, p) + 0.05 * np.random.default_rng(0).standard_normal(
        (len(p), table.shape[1]))
    assert aliasing.mirror_evidence(aliasing.distances(f, fine), p % 1.0, fine).dof == 5


def _scripted_watch(rate: float, n: int) -> tuple[np.ndarray, aliasing.AliasWatch, Any]:
    """The pulses' distances to the fine table of a pattern that shows every angle, for
    a fan at ``rate`` blade periods per pulse over ``n`` pulses, a fresh alias watch and
    a real Tracker locked at pulse 0 whose line the test sets (scripted, as in
    ``_watch_on``)."""
    from bladesonar.dsp.tracking import Tracker, TrackerSettings
    table = _table(visible=None)
    _, f = _pulses(table, rate, n=n)
    fine = aliasing.fine_table(table)
    watch = aliasing.AliasWatch(fine, 170, 0.03, min_rate=0.003)
    tr = Tracker(TrackerSettings(max_rate=0.45))
    tr.start_k = tr.locked_k = 0
    tr.P = np.diag([1e-4, 1e-8])
    return aliasing.distances(f, fine), watch, tr


def test_a_winner_moves_the_track_only_once_each_angle_was_seen_enough():
    """A track locked on the alias 5/12 of 1/12 blade period per pulse (the pulses see
    the same 12 angles), the true line clearly better from the first check on: the watch moves
    the track to the true line, but not before the window since the lock has seen each
    angle ``SEEN_EACH`` times (48 pulses: a start at 1/12 in a random room was moved to
    its mirror on 41, where one check's winner had swung to the wrong line). The track is
    scripted (a real Tracker whose line is set), as in ``_watch_on``."""
    rate, n = 1 / 12, 120
    dist, watch, tr = _scripted_watch(rate, n)
    moved_at = None
    for i in range(n):
        if tr.relocks == 0:
            tr.x = np.array([(0.5 + 5 * rate * i) % 1.0, 5 * rate])   # on the alias
        else:
            assert tr.x is not None and tr.last_k is not None
            tr.x = np.array([(tr.x[0] + tr.x[1] * (i - tr.last_k)) % 1.0, tr.x[1]])
            moved_at = i if moved_at is None else moved_at
        tr.last_k = i
        watch.push(i, dist[i], float(tr.x[0]))
        # (``resting``: the mirror check, which moves tracks by its own evidence, is not
        # run; the alias check is)
        watch.check(tr, accel=0.0, moving=lambda: True, resting=True)
    assert moved_at is not None and tr.x is not None
    assert (watch.moves, watch.mirror_moves) == (1, 0)
    assert float(tr.x[1]) == pytest.approx(rate, abs=1e-6)
    assert 48 <= moved_at <= 48 + 24, moved_at     # (unbounded, it moved on pulse 18)


def _follow_line(watch: aliasing.AliasWatch, tr: Any, dist: np.ndarray, n: int, *,
                 moving: bool) -> int | None:
    """Pulses 0..n-1 to a scripted track that follows its line (``tr.x``, as the watch
    last set it) and to the watch after each; the pulse at which the watch first moved
    the track (None: never)."""
    moved_at = None
    for i in range(n):
        assert tr.x is not None and tr.last_k is not None
        tr.x = np.array([(tr.x[0] + tr.x[1] * (i - tr.last_k)) % 1.0, tr.x[1]])
        if tr.relocks and moved_at is None:
            moved_at = i
        tr.last_k = i
        watch.push(i, dist[i], float(tr.x[0]))
        watch.check(tr, accel=0.0, moving=lambda: moving, resting=True)
    return moved_at


@pytest.mark.parametrize("moving", [True, False])
def test_a_track_standing_while_the_fan_moves_is_checked_though_a_ramp_verified_it(moving):
    """The fan turns at 1/7 blade period per pulse; the track stands at zero on the line
    the strobed matches draw (a table clear at one angle gives a clear match once a
    period, at nearly the same phase) and was verified by the ramp that brought it there
    (spent held-out 5500017: 165 s so). While the long meter sees the fan move, a ramp's
    verdict does not exempt a standing track from the alias check: it is moved to the
    true line (the table here shows every angle, so the line fit can tell). With the fan
    not seen to move, the standing track is left alone. The track is scripted (a real
    Tracker whose line is set), as in ``_watch_on``."""
    rate, n = 1 / 7, 170
    dist, watch, tr = _scripted_watch(rate, n)
    tr.x = np.array([0.5, 0.0])
    tr.last_k = 0
    watch.verified = tr.identity                # (as a ramp verifies it)
    _follow_line(watch, tr, dist, n, moving=moving)     # (standing until moved)
    assert tr.x is not None
    if moving:
        assert watch.moves == 1 and float(tr.x[1]) == pytest.approx(rate, abs=1e-6)
    else:
        assert watch.moves == 0 and float(tr.x[1]) == 0.0


@pytest.mark.parametrize("on_alias", [True, False])
def test_a_verified_track_half_a_blade_period_per_pulse_off_is_moved_back(on_alias):
    """The fan turns at 0.29 blade period per pulse, near no p/q; a ramp through 1/4 left
    the track on the line half a blade period per pulse away (0.29 - 1/2 = -0.21: the
    other way) and verified it (spent held-out 5900018: the wrong way published for 10 s,
    then 24 s unknown). The watch looks again at lines a half, a third and a quarter
    of a blade period per pulse away, and moves the track to the one that fits
    (``AliasWatch._check_shifts``); a track on the true line stays there. The track is
    scripted (a real Tracker whose line is set), as in ``_watch_on``."""
    rate, n = 0.29, 170
    dist, watch, tr = _scripted_watch(rate, n)
    line = rate - 0.5 if on_alias else rate
    tr.x = np.array([0.5, line])
    tr.last_k = 0
    watch.verified = tr.identity                # (as a ramp verifies it)
    moved_at = _follow_line(watch, tr, dist, n, moving=True)
    assert tr.x is not None
    if on_alias:
        assert watch.moves == 1 and float(tr.x[1]) == pytest.approx(rate, abs=1e-6)
        assert moved_at is not None and moved_at <= 170 // 2 + 2 * 8 + 1, moved_at
    else:
        assert watch.moves == 0 and float(tr.x[1]) == rate
