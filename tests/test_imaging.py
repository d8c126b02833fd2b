"""The numbers behind the pictures, against the simulator's geometry and known rates."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bladesonar import config, imaging
from bladesonar.io.scene_file import load_scene
from bladesonar.sim.render import simulate


@pytest.fixture(scope="module")
def scene(repo_root):
    return load_scene(repo_root / "config" / "scenes" / "paper-room.yaml")


def _circ(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs((np.asarray(a) - np.asarray(b) + math.pi) % (2 * math.pi) - math.pi)


# ------------------------------------------------------------------ range-doppler


@pytest.mark.parametrize("rate", [0.37, 0.29])
def test_rd_peak_is_a_blade_pass_harmonic_at_the_direct_echo_range(scene, rate):
    """The direct blade echo flashes twice per blade per turn, so its doppler spectrum is a
    comb at multiples of the blade-pass frequency K f; the strongest line at the direct
    echo's one-way range must sit on that comb (an unaliased harmonic) and the range on the
    truth's blade path lengths / 2."""
    cfg = config.Config()
    x, truth = simulate(scene, cfg, 12.0, schedule=f"ccw:{rate}:12", snr_db=20, seed=4)
    blade = np.array([p["delay"] for r in truth["pulses"] for p in r["paths"]
                      if p["kind"] == "blade"]) * cfg.scene.speed_of_sound \
        / cfg.audio.sample_rate / 2
    m = imaging.rd_map(x, cfg)
    f, r = m.peak(blade.min() - 0.01, blade.max() + 0.01, min_hz=0.3)
    kf = cfg.scene.blades * rate
    n = f / kf
    assert 1 <= abs(round(n)) <= cfg.prf_hz / (2 * kf)
    assert abs(n - round(n)) < 0.12, (f, kf)
    assert blade.min() - 0.01 <= r <= blade.max() + 0.01
    # every moving cell of the map is on the comb: the 5 strongest lines at that range
    col = m.power_db[:, np.argmin(np.abs(m.range_m - r))]
    df = m.doppler_hz[1] - m.doppler_hz[0]
    peaks = [i for i in range(1, len(col) - 1) if col[i] >= col[i - 1] and col[i] >= col[i + 1]
             and abs(m.doppler_hz[i]) > 0.3]
    top = sorted(peaks, key=lambda i: col[i], reverse=True)[:5]
    for i in top:
        k = m.doppler_hz[i] / kf
        assert abs(k - round(k)) * kf < 1.5 * df, m.doppler_hz[i]
    # the gate the analysis would use starts before the direct echo
    assert m.gate.start_m <= blade.min()
    # and the range axis is one-way: the coupling edge is at 0 m, the last bin below one PRI
    assert m.range_m[0] == 0.0
    assert m.range_m[-1] < cfg.max_range_m


# ------------------------------------------------------------------ ISAR


def _isar(scene, cfg, rate, *, wall_bounces=False, snr=20.0, seed=1, assumed=None):
    x, _ = simulate(scene, cfg, 5.3, schedule=f"{'ccw' if rate > 0 else 'cw'}:{abs(rate)}:6",
                    snr_db=snr, seed=seed, wall_bounces=wall_bounces, include_paths=False)
    p, e = imaging.valid_pulses(imaging.aligned(x, cfg), 175)
    assert len(p) == 175
    return imaging.backproject(p - p.mean(axis=0), e / cfg.audio.sample_rate, delay0=0.0,
                               fs=cfg.audio.sample_rate, c=cfg.scene.speed_of_sound,
                               sensor=scene.sensor, centre=scene.fan_centre,
                               rate_hz=rate if assumed is None else assumed,
                               start_rad=scene.start_angle_rad, extent_m=0.9, n_pix=256)


@pytest.mark.parametrize("blades", [4, 3])
def test_isar_shows_the_blades_where_they_are(scene, blades):
    """Brightest spokes: K of them, 2 pi / K apart, along the true blade directions of the
    fan frame (blade j at 2 pi j / K), bright over the blade span and dark past the tips."""
    cfg = config.replace(config.Config(), scene={"blades": blades})
    sc = dataclasses.replace(scene, blades=blades)
    img = _isar(sc, cfg, 0.5)
    assert img.image.shape == (256, 256)
    r0, r1 = sc.hub_radius_m, sc.tip_radius_m
    ang = imaging.spokes(img, blades, r0 + 0.05, r1 - 0.1)
    true = 2 * math.pi * np.arange(blades) / blades
    assert np.all(_circ(ang, true) < math.radians(3)), np.degrees(ang)
    r, th, v = imaging.polar(img, n_r=90, n_theta=720)
    cols = np.concatenate([np.arange(i - 2, i + 3) % 720 for i in
                           np.round(ang / (2 * math.pi) * 720).astype(int)])
    excess = v[:, cols].mean(axis=1) - v.mean(axis=1)   # spoke over ring average
    on = excess[(r > r0 + 0.1) & (r < r1 - 0.1)].mean()
    past = excess[(r > r1 + 0.12) & (r < r1 + 0.22)].mean()
    assert on > 4 * max(past, 0.0)
    # the spoke reaches out to the blade tip (half brightness within 12 cm of it)
    half = r[(excess > 0.5 * on) & (r > r0)].max()
    assert abs(half - r1) < 0.12, half


def test_isar_multipath_does_not_hide_the_blades(scene):
    cfg = config.Config()
    img = _isar(scene, cfg, 0.5, wall_bounces=True)
    ang = imaging.spokes(img, 4, 0.15, 0.55)
    assert np.all(_circ(ang, np.arange(4) * math.pi / 2) < math.radians(3))


@pytest.mark.slow
def test_isar_direct_path_cannot_tell_cw_from_ccw(scene):
    """The paper's point: with the direct path alone, a CW and a CCW run (same start offset
    and noise seed, so direction is the only difference) give the same image up to a
    rotation, and one recording imaged with the wrong direction gives its mirror image; a
    fan with another blade count does not match."""
    cfg = config.Config()
    ring = dict(r_lo=scene.hub_radius_m + 0.05, r_hi=scene.tip_radius_m)
    ccw = _isar(scene, cfg, 0.5)
    cw = _isar(scene, cfg, -0.5)
    cw_as_ccw = _isar(scene, cfg, -0.5, assumed=0.5)
    assert imaging.rotation_match(ccw, cw, **ring)[0] > 0.9
    assert imaging.rotation_match(cw, cw_as_ccw, mirror=True, **ring)[0] > 0.9
    cfg3 = config.replace(cfg, scene={"blades": 3})
    three = _isar(dataclasses.replace(scene, blades=3), cfg3, 0.5)
    assert imaging.rotation_match(ccw, three, mirror=True, **ring)[0] < 0.5


def test_backprojection_of_one_point_echo_focuses_on_that_point():
    """A synthetic point scatterer on the rotating frame at (0.3, 0.1) m: the image peak
    lands on it (checks the frame, the rotation sense and the delay convention)."""
    fs, c = 44100.0, 343.0
    sensor, centre = (0.0, 0.0), (2.0, 0.5)
    rate, n, L = -0.4, 120, 700
    t = np.arange(n) / 34.0
    th = 2 * math.pi * rate * t
    p = np.array([0.3, 0.1])
    world = np.stack([np.cos(th) * p[0] - np.sin(th) * p[1] + centre[0],
                      np.sin(th) * p[0] + np.cos(th) * p[1] + centre[1]], axis=1)
    delay = 2 * np.hypot(*(world - sensor).T) / c * fs
    m = np.arange(L)
    pulses = np.sinc(m[None, :] - delay[:, None])    # band-limited impulse at each delay
    img = imaging.backproject(pulses, t, delay0=0.0, fs=fs, c=c, sensor=sensor,
                              centre=centre, rate_hz=rate, extent_m=0.5, n_pix=101)
    iy, ix = np.unravel_index(int(np.argmax(img.image)), img.image.shape)
    assert abs(img.axis_m[ix] - 0.3) < 0.02 and abs(img.axis_m[iy] - 0.1) < 0.02


# ------------------------------------------------------------------ distance matrix


@pytest.fixture(scope="module")
def ref_pulses(scene):
    cfg = config.Config()
    x, _ = simulate(scene, cfg, 6.0, schedule="ccw:0.5:6", snr_db=20, seed=1,
                    include_paths=False)
    gate = imaging.rd_map(x, cfg).gate
    p, _ = imaging.valid_pulses(imaging.aligned(x, cfg, gate), 175)
    return cfg, gate, imaging.features(p, cfg)


@pytest.mark.parametrize("sched,ratio", [("cw:0.7:6", -1.4), ("ccw:0.3:6", 0.6),
                                         ("cw:1.6:6", -3.2), ("ccw:0.5:6", 1.0)])
def test_stripe_slope_is_the_rate_ratio(scene, ref_pulses, sched, ratio):
    cfg, gate, fa = ref_pulses
    x, _ = simulate(scene, cfg, 6.0, schedule=sched, snr_db=20, seed=7, include_paths=False)
    p, _ = imaging.valid_pulses(imaging.aligned(x, cfg, gate), 175)
    d = imaging.distance_matrix(fa, imaging.features(p, cfg))
    assert d.shape == (175, 175)
    st = imaging.stripe_slope(d)
    assert np.sign(st.slope) == np.sign(ratio)
    assert abs(st.slope - ratio) < 0.03 * abs(ratio), st
    # rows: the reference's blade phase per pulse (2 Hz / PRF)
    assert abs(st.row_cycles - 4 * 0.5 / cfg.prf_hz) < 0.002
    # the drawn stripe centres lie on low distances: mean along them is below the median
    lines = st.lines(np.arange(175), 175)
    vals = [d[int(round(i)), j] for ii in lines for j, i in enumerate(ii) if 0 <= round(i) < 175]
    z = d - d.mean(1, keepdims=True) - d.mean(0, keepdims=True) + d.mean()
    zv = [z[int(round(i)), j] for ii in lines for j, i in enumerate(ii) if 0 <= round(i) < 175]
    assert np.mean(zv) < 0 and len(vals) > 100


def test_distance_matrix_is_the_energy_norm():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(5, 7)), rng.normal(size=(4, 7))
    d = imaging.distance_matrix(a, b)
    assert np.allclose(d, ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1))


# ------------------------------------------------------------------ simulated paths


def test_direct_path_ranges_follow_the_closed_form(scene):
    cfg = config.Config()
    s = imaging.path_ranges(scene, cfg, 0.5, 68, kinds=("blade",))
    S, C = np.array(scene.sensor), np.array(scene.fan_centre)
    d = S - C
    for k in range(68):
        want = []
        for j in range(4):
            phi = s.angle_rad[k] + 2 * math.pi * j / 4
            u = np.array([math.cos(phi), math.sin(phi)])
            foot = d @ u
            if scene.hub_radius_m <= foot <= scene.tip_radius_m:
                want.append(abs(d @ np.array([-u[1], u[0]])))
        got = np.sort(s.range_m[k][np.isfinite(s.range_m[k])])
        assert np.allclose(got, np.sort(want), atol=1e-9)


def _mismatch(a: np.ndarray, b: np.ndarray) -> float:
    """Mean distance from each finite range of a to the nearest range of b at the same
    sample (and back); large when one has echoes the other lacks."""
    tot, n = 0.0, 0
    for ra, rb in ((a, b), (b, a)):
        for x, y in zip(ra, rb, strict=True):
            x, y = x[np.isfinite(x)], y[np.isfinite(y)]
            for v in x:
                tot += np.min(np.abs(y - v)) if len(y) else 1.0
                n += 1
    return tot / max(n, 1)


def test_cw_and_ccw_differ_only_with_multipath(scene):
    """Over one blade period, the direct echoes of a cw turn are a time shift of the ccw
    ones (mirror symmetry), the multipath echoes are not (the paper's Fig. of range series)."""
    cfg = config.Config()
    n = 360
    # sample one blade period finely: rate chosen so that n pulses span exactly 1/K turn
    rate = cfg.prf_hz / (4 * n)
    for kinds, expect_same in ((("blade",), True), (("wall_blade",), False)):
        ccw = imaging.path_ranges(scene, cfg, rate, n, kinds=kinds).range_m
        cw = imaging.path_ranges(scene, cfg, -rate, n, kinds=kinds).range_m
        best = min(_mismatch(ccw, np.roll(cw, s, axis=0)) for s in range(0, n, 2))
        if expect_same:
            assert best < 0.002, best
        else:
            assert best > 0.02, best


# ------------------------------------------------------------------ track rows


def test_track_series_unwraps_and_finds_reversals():
    rows = []
    ph = 0.0
    for k in range(60):
        ph = (ph + (0.08 if k < 30 else -0.1)) % 1.0
        rows.append(dict(t_s=k / 34, pulse=k, phase=(ph + 0.01) % 1.0, quality=0.5,
                         track_phase=ph, track_sd=0.01, outlier=False,
                         direction="same" if k < 35 else ("unknown" if k < 40 else "reversed"),
                         relative_rate=1.0 if k < 30 else -1.25, confidence=0.9))
    s = imaging.track_series(rows)
    d = np.diff(s.track)
    assert np.all(d[:29] > 0.07) and np.all(d[30:] < -0.09)
    assert np.allclose(s.matched - s.track, 0.01)
    assert np.allclose(s.reversals, [40 / 34])
    assert np.allclose(imaging.reversal_times("ccw:0.5:3,stop:0:2,cw:0.4:5,cw:0.2:1"), [5.0])
