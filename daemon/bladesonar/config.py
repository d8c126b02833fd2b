"""Settings: one typed, frozen object built once from YAML and validated at the boundary.

Each section is a frozen dataclass; every field declares its default, its domain and a
one-line doc (with unit) in ``metadata``. Validation walks those declarations, so the
schema, the error messages and the commented example file (config/bladesonar.example.yaml)
all come from one place. Downstream code receives these objects, never raw dicts.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import ConfigError
from .schema import build, fields_of, opt, section_type

#: Longest ``sim.schedule``, characters: a simulated day is a legitimate long value (the
#: soak's two hours take about 1900 characters), so it may hold 64 Ki (about 3000
#: segments, more than two simulated days; the config file itself is capped at 256 KiB);
#: every other text value stops at ``schema.MAX_TEXT``.
MAX_SCHEDULE = 1 << 16


@dataclass(frozen=True)
class AudioSettings:
    backend: str = opt("alsa", "where pulses are played and recorded: a bare ALSA card, "
                       "a PipeWire server's graph (phones, desktop images), auto (PipeWire "
                       "if one runs, else ALSA; PulseAudio is refused), or the in-process "
                       "scene simulator", choices=("alsa", "pipewire", "auto", "sim"))
    sample_rate: int = opt(44100, "sample rate of playback and capture", lo=8000,
                           hi=192000, unit="Hz")
    playback_device: str = opt("default", "ALSA PCM name for the speaker (pipewire: the "
                               "sink's node.name; default: the server's default sink)")
    capture_device: str = opt("default", "ALSA PCM name for the microphone (pipewire: the "
                              "source's node.name; default: the server's default source)")
    format: str = opt("S16_LE", "ALSA sample format of both streams",
                      choices=("S16_LE", "S32_LE"))
    period_pulses: int = opt(4, "ALSA period in PRIs: the audio threads wake once a period "
                             "(a period of one PRI woke them 68 times a second, a quarter "
                             "of the daemon's CPU); 1 for a card that accepts no other",
                             lo=1, hi=64, unit="PRIs")
    buffer_periods: int = opt(4, "ALSA buffer size in periods (of period_pulses PRIs)",
                              lo=2, hi=64)
    ring_pulses: int = opt(256, "capture ring between the audio thread and processing",
                           lo=8, hi=65536, unit="pulses")


@dataclass(frozen=True)
class WaveformSettings:
    pri_samples: int = opt(1297, "pulse repetition interval; PRF = sample_rate / pri_samples",
                           lo=64, hi=1_000_000, unit="samples")
    pulse: str = opt("impulse", "transmit pulse shape: the paper's narrow band-limited "
                     "impulse, or a Hann-windowed click of pulse_samples",
                     choices=("impulse", "hann"))
    pulse_samples: int = opt(1, "length of the Hann pulse (ignored for impulse)", lo=1,
                             hi=256, unit="samples")
    amplitude: float = opt(0.5, "peak amplitude of the transmitted pulse (full scale = 1)",
                           lo=0.0, hi=1.0, lo_open=True)


@dataclass(frozen=True)
class SceneSettings:
    blades: int = opt(4, "number of blades K; the echo pattern repeats every 1/K turn",
                      lo=1, hi=16)
    speed_of_sound: float = opt(343.0, "c, for range = c * delay / 2", lo=200.0, hi=2000.0,
                                unit="m/s")
    gate_start_m: float | None = opt(None, "start of the one-way range gate; null: from the "
                                     "target range found in the reference", lo=0.0, hi=1000.0,
                                     unit="m", nullable=True)
    gate_stop_m: float | None = opt(None, "end of the one-way range gate; null: the last "
                                    "unambiguous range (one PRI)", lo=0.0, hi=1000.0,
                                    unit="m", nullable=True, lo_open=True)
    target_range_m: float | None = opt(None, "one-way range of the fan centre if known; null: "
                                       "found from the reference's doppler energy",
                                       lo=0.0, hi=1000.0, unit="m", nullable=True)
    downdraft_rotation: str = opt("ccw", "which way the fan turns, seen from below, when it "
                                  "blows down (most fans: ccw); turns a measured airflow "
                                  "into a rotation", choices=("ccw", "cw"))


@dataclass(frozen=True)
class AnalysisSettings:
    """Reference building and matching (owned by the pipeline: dsp/ and the analysis modules)."""

    phase_bins: int = opt(0, "angular bins of the reference table; 0: four per reference "
                          "pulse per blade period (folding many periods fills the angles "
                          "between pulses), 16 to 256", lo=0, hi=4096)
    min_periods: float = opt(3.0, "blade periods a reference must hold to be folded",
                             lo=1.0, hi=10000.0)
    features: str = opt("envelope", "what is matched: the envelope of the moving echoes "
                        "(robust to sub-sample jitter and drift) or the raw samples",
                        choices=("envelope", "raw"))
    envelope_smooth: int = opt(5, "moving-average length applied to the envelope along range",
                               lo=1, hi=64, unit="samples")
    static_window_s: float = opt(3.0, "time constant of the running mean pulse (the static "
                                 "room) removed before matching", lo=0.1, hi=600.0, unit="s")
    gate_margin_m: float = opt(0.2, "with a null scene.gate_start_m the gate opens this much "
                               "before the target range", lo=0.0, hi=10.0, unit="m")
    min_pulses: int = opt(64, "fewest pulses a recording to analyse must hold", lo=16,
                          hi=1_000_000)
    max_phase_per_pulse: float = opt(0.4, "largest blade phase step per pulse accepted in a "
                                     "reference (1/2 is the aliasing limit PRF/(2K))",
                                     lo=0.05, hi=0.5)
    line_snr_min: float = opt(8.0, "strongest doppler line over the noise floor needed to "
                              "call a reference target moving", lo=1.5, hi=1e6)
    max_clip_fraction: float = opt(0.01, "clipped samples above this fraction refuse a "
                                   "recording (below: a warning)", lo=0.0, hi=1.0)


@dataclass(frozen=True)
class TrackingSettings:
    """The circular Kalman filter on (phase, phase rate) (owned by dsp/tracking.py)."""

    slew_limit: float = opt(4.0, "largest |rate| relative to the reference the tracker "
                            "follows (the paper: 4 reference pulses per pulse)", lo=0.1,
                            hi=100.0)
    rate_noise: float = opt(0.0003, "rate random walk per pulse (standard deviation, in "
                            "reference cycles per pulse): how fast the fan may speed up or "
                            "slow down", lo=0.0, hi=0.5)
    max_ramp_hz_s: float = opt(0.15, "steepest speed ramp followed without lag: a second "
                               "filter carrying the rate's change runs beside the "
                               "constant-rate track and gives the published rate while the "
                               "speed is changing; 0: the constant-rate track alone",
                               lo=0.0, hi=100.0, unit="Hz/s")
    meas_sigma: float = opt(0.02, "phase noise of a perfect match, in blade periods; scaled "
                            "by 1/match quality", lo=1e-6, hi=0.5)
    gate_sigma: float = opt(4.0, "innovation gate: matches further than this many standard "
                            "deviations are outliers", lo=1.0, hi=100.0)
    reacquire_after: int = opt(6, "outliers in a row that restart the track (a reversal or "
                               "a drop-out)", lo=1, hi=10000, unit="pulses")
    init_pulses: int = opt(24, "matches the circular-regression start uses", lo=4,
                           hi=10000, unit="pulses")
    min_coherence: float = opt(0.6, "coherence of those matches needed to lock (random "
                               "phases with the matches' quality weights reach about this "
                               "at the median: docs/dynamics.md)", lo=0.0, hi=1.0)
    motion_threshold: float = opt(1.15, "pulse variance over the most-alike-lag difference "
                                  "below which the target is called stopped (the short "
                                  "meter uses what noise alone reads in the range gate "
                                  "instead when that is higher: a short gate; and it "
                                  "rises, at most 0.15, by what the device reads at "
                                  "rest beyond noise: a reverberant room under drift)",
                                  lo=1.0, hi=10.0)
    min_confidence: float = opt(0.5, "below this confidence the direction is reported as "
                                "unknown", lo=0.0, hi=1.0)
    rate_floor_hz: float = opt(0.05, "no direction is claimed for a fan turning slower than "
                               "this (it is stopped or unknown)", lo=0.0, hi=10.0, unit="Hz")
    confirm_s: float = opt(0.5, "a new turning state (start, reversal) must hold this long "
                           "before it is published and its event sent", lo=0.0, hi=60.0,
                           unit="s")
    max_reversal_hz_s: float = opt(0.3, "fastest change of a fan from one direction "
                                   "through zero to the other: a reversal claimed sooner "
                                   "after the last answer of the old direction waits "
                                   "until it could be true (a track lost and taken up "
                                   "on the mirror of the blade pattern), and a fan "
                                   "last seen slower than it could be braked to zero "
                                   "within half a blade period is not called stopped at "
                                   "once (it may be reversing out of view); 0: no wait",
                                   lo=0.0, hi=100.0, unit="Hz/s")
    decide_every: int = opt(4, "pulses between decisions (matching and tracking run on every "
                            "pulse): 4 at 34 pulses/s adds at most 0.12 s to an event and "
                            "quarters the cost of the motion meters; 1: every pulse", lo=1,
                            hi=1000, unit="pulses")


@dataclass(frozen=True)
class DaemonSettings:
    """The long-running service (bladesonar run)."""

    state_dir: str = opt("/var/lib/bladesonar", "where the reference is stored "
                         "(systemd StateDirectory)")
    reference: str = opt("reference.npz", "reference file name, relative to state_dir "
                         "unless absolute")
    window_s: float = opt(5.0, "observation window the published estimate describes",
                          lo=0.25, hi=3600.0, unit="s")
    block_pulses: int = opt(8, "capture periods gathered and analysed together, each "
                            "block ending where a decision's pulse is complete (every "
                            "block_pulses / tracking.decide_every-th decision, on pulse "
                            "numbers: the same pulses whatever the latency): the CPU per "
                            "pulse falls with it (the numpy work of a block costs about "
                            "the same for 1 pulse as for 8), a decision between two ends "
                            "is published up to that many PRIs later (8: 0.12 s); the "
                            "answers are the same", lo=1, hi=1000, unit="pulses")


@dataclass(frozen=True)
class SimSettings:
    """The in-process scene simulator behind audio.backend: sim (demo, self-test)."""

    scene: str = opt("scenes/paper-room.yaml", "scene file (relative to this config "
                     "file's folder unless absolute)")
    schedule: str = opt("ccw:0.45:20", "rotation schedule as DIR:RATE_HZ:SECONDS,... "
                        "(DIR cw, ccw or stop); SECONDS~RAMP_S ramps linearly from the "
                        "previous rate over the segment's first RAMP_S s; an item "
                        "wobble:A:T scales the speed by 1 + A sin(2 pi t / T); the last "
                        "segment repeats", max_len=MAX_SCHEDULE)
    snr_db: float = opt(20.0, "fan-echo to noise power inside the range gate", lo=-30.0,
                        hi=120.0, unit="dB")
    seed: int = opt(1, "random seed of the simulated noise and start offset", lo=0,
                    hi=2**32 - 1)
    realtime: bool = opt(True, "pace the simulated audio at the real sample rate")


@dataclass(frozen=True)
class MqttSettings:
    host: str | None = opt(None, "broker host name; null: print the messages as JSON lines "
                           "on stdout instead", nullable=True)
    port: int = opt(1883, "broker TCP port", lo=1, hi=65535)
    topic_prefix: str = opt("bladesonar", "topics are <topic_prefix>/<device_id>/...",
                            pattern=r"[^#+\s]+")
    discovery: bool = opt(True, "publish Home Assistant MQTT discovery configs")
    discovery_prefix: str = opt("homeassistant", "Home Assistant discovery prefix",
                                pattern=r"[^#+\s]+")
    client_id: str | None = opt(None, "MQTT client id; null: bladesonar-<device_id>",
                                nullable=True)
    username: str | None = opt(None, "broker user name", nullable=True)
    password_file: str | None = opt(None, "file holding the broker password (never logged)",
                                    nullable=True)
    password_env: str | None = opt(None, "environment variable holding the broker password",
                                   nullable=True)
    tls: bool = opt(False, "connect with TLS (certificates are verified)")
    ca_certs: str | None = opt(None, "CA bundle for TLS; null: the system's", nullable=True)
    certfile: str | None = opt(None, "client certificate for TLS", nullable=True)
    keyfile: str | None = opt(None, "client key for TLS", nullable=True)
    keepalive_s: int = opt(60, "MQTT keepalive", lo=5, hi=3600, unit="s")
    publish_interval_s: float = opt(5.0, "state is published at this interval (and at once "
                                    "on a change of direction or start/stop)", lo=0.1,
                                    hi=3600.0, unit="s")
    stats_interval_s: float = opt(60.0, "interval of the stats message", lo=1.0, hi=86400.0,
                                  unit="s")
    event_queue: int = opt(1000, "events kept while the broker is away (oldest dropped, "
                           "and counted, beyond this)", lo=1, hi=1_000_000)
    device_name: str | None = opt(None, "the device's name in Home Assistant (entity names "
                                  "follow it: 'Living room fan Rotation'); null: made from "
                                  "device_id ('living-room-fan' -> 'Living room fan')",
                                  nullable=True)
    commands: bool = opt(True, "accept commands on <topic_prefix>/<device_id>/command/... "
                         "(learn or forget the reference, set its direction) and announce "
                         "their buttons to Home Assistant; any client of the broker can send "
                         "them")


@dataclass(frozen=True)
class ReferenceSettings:
    """How the daemon learns its reference by itself and watches that it still fits."""

    auto_learn: bool = opt(True, "with no reference stored, learn one from the first steady "
                           "rotation seen (directions are then relative until the reference "
                           "direction is set)")
    learn_seconds: float = opt(20.0, "length of the recording a reference is learned from "
                               "(live, in the running daemon); at most 2^20 samples (23.8 s "
                               "at 44.1 kHz)", lo=3.0, hi=60.0, unit="s")
    min_quality: float = opt(0.5, "a learned reference is kept only if this share of its "
                             "recording's energy is explained by its table (a steady fan "
                             "gives 0.75-0.85; a fan changing speed less)", lo=0.0, hi=1.0)
    retry_s: float = opt(30.0, "wait after a failed automatic learning before the next "
                         "try; doubles after each failure up to retry_max_s", lo=1.0,
                         hi=86400.0, unit="s")
    retry_max_s: float = opt(600.0, "longest wait between automatic learning tries",
                             lo=1.0, hi=86400.0, unit="s")
    stale_fit: float = opt(0.6, "the reference is called stale when its fit (match quality "
                           "while the fan turns, 1 = as the reference promised) stays below "
                           "this over stale_after_s of turning", lo=0.0, hi=1.0)
    stale_after_s: float = opt(180.0, "seconds of turning the fit is averaged over", lo=10.0,
                               hi=86400.0, unit="s")
    auto_relearn: bool = opt(False, "learn a new reference by itself when the stored one is "
                             "stale or invalid (the old one is kept as "
                             "<daemon.reference>.previous)")


@dataclass(frozen=True)
class Config:
    device_id: str = opt("bladesonar", "this device's id in topics and in Home Assistant",
                         pattern=r"[A-Za-z0-9_-]+")
    audio: AudioSettings = field(default_factory=AudioSettings)
    waveform: WaveformSettings = field(default_factory=WaveformSettings)
    scene: SceneSettings = field(default_factory=SceneSettings)
    analysis: AnalysisSettings = field(default_factory=AnalysisSettings)
    tracking: TrackingSettings = field(default_factory=TrackingSettings)
    mqtt: MqttSettings = field(default_factory=MqttSettings)
    daemon: DaemonSettings = field(default_factory=DaemonSettings)
    reference: ReferenceSettings = field(default_factory=ReferenceSettings)
    sim: SimSettings = field(default_factory=SimSettings)
    #: Folder of the config file; relative paths in it are resolved against this.
    base_dir: str = field(default=".", metadata=dict(internal=True))

    def path(self, p: str) -> Path:
        """A path from the config, resolved against the config file's folder."""
        q = Path(p).expanduser()
        return q if q.is_absolute() else Path(self.base_dir) / q

    @property
    def reference_path(self) -> Path:
        """Where the daemon keeps its reference: daemon.reference inside daemon.state_dir."""
        return self.path(self.daemon.state_dir) / Path(self.daemon.reference).expanduser()

    @property
    def prf_hz(self) -> float:
        """Pulse repetition frequency."""
        return self.audio.sample_rate / self.waveform.pri_samples

    @property
    def max_range_m(self) -> float:
        """Last unambiguous one-way range: echoes later than one PRI fold into the next."""
        return self.scene.speed_of_sound * self.waveform.pri_samples / self.audio.sample_rate / 2


# --------------------------------------------------------------------------------------
# Validation


#: Most samples a reference is folded from (io/wav.py REFERENCE_SAMPLES: its memory).
_REFERENCE_SAMPLES = 1 << 20


def _check_cross(cfg: Config, lines: Mapping[str, int], source: str | None) -> None:
    r = cfg.reference
    longest = _REFERENCE_SAMPLES / cfg.audio.sample_rate
    if r.learn_seconds > longest + 1e-9:
        raise ConfigError("reference.learn_seconds", r.learn_seconds,
                          f"must be at most {longest:.1f} s at {cfg.audio.sample_rate} Hz "
                          "(a reference folds at most 2^20 samples); lower it",
                          source=source, line=lines.get("reference.learn_seconds"))
    if r.retry_max_s < r.retry_s:
        raise ConfigError("reference.retry_max_s", r.retry_max_s,
                          f"must be at least reference.retry_s ({r.retry_s:g} s)",
                          source=source, line=lines.get("reference.retry_max_s"))
    s = cfg.scene
    if s.gate_start_m is not None and s.gate_stop_m is not None and s.gate_stop_m <= s.gate_start_m:
        raise ConfigError("scene.gate_stop_m", s.gate_stop_m,
                          f"must be greater than scene.gate_start_m ({s.gate_start_m:g} m)",
                          source=source, line=lines.get("scene.gate_stop_m"))
    if s.gate_stop_m is not None and s.gate_stop_m > cfg.max_range_m + 1e-9:
        raise ConfigError("scene.gate_stop_m", s.gate_stop_m,
                          f"must be at most {cfg.max_range_m:.3f} m, the last unambiguous range "
                          f"for pri_samples={cfg.waveform.pri_samples} at "
                          f"{cfg.audio.sample_rate} Hz (echoes later than one PRI fold into "
                          "the next pulse); raise waveform.pri_samples or lower the gate",
                          source=source, line=lines.get("scene.gate_stop_m"))


def from_mapping(data: Any, *, source: str | None = None,
                 lines: Mapping[str, int] | None = None) -> Config:
    """Validate a parsed YAML document and build the settings object."""
    lines = lines or {}
    cfg: Config = build(Config, data, "", lines, source)
    _check_cross(cfg, lines, source)
    return cfg


def replace(cfg: Config, **sections: Mapping[str, Any]) -> Config:
    """A copy of cfg with some keys changed, validated like a file (e.g. from CLI options)."""
    data = to_mapping(cfg)
    for sec, values in sections.items():
        if isinstance(values, Mapping):
            data.setdefault(sec, {}).update(values)
        else:
            data[sec] = values
    return dataclasses.replace(from_mapping(data), base_dir=cfg.base_dir)


def to_mapping(cfg: Config) -> dict[str, Any]:
    """The settings as plain data (what a reference file or a status message records)."""
    data = dataclasses.asdict(cfg)
    data.pop("base_dir", None)
    return data


def iter_fields(cls: type = Config, prefix: str = ""
                ) -> Iterator[tuple[str, dataclasses.Field[Any]]]:
    """Yield (dotted key, field) for every leaf setting: drives docs and the example file."""
    for f in fields_of(cls).values():
        section = section_type(f)
        if section is not None:
            yield from iter_fields(section, f"{prefix}{f.name}.")
        else:
            yield f"{prefix}{f.name}", f
