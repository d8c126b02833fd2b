"""``bladesonar simulate``: render a scene to a mono WAV plus a truth sidecar (OUT.truth.json).

A thin edge: parse options, load the scene and config, stream the pure renderer's chunks
into the WAV and truth writers, print a one-line JSON summary.
"""

from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Callable

    from ..config import Config
    from ..sim.render import Simulator
    from ..sim.scene import Scene
    from ..sim.scene3d import Scene3D

EPILOG = """\
conventions:
  floor plan x right, y up, seen from above; angles and rates ccw-positive; fan angle 0 puts
  blade 0 along +x. A 3-D scene (room.size [x, y, z], z up) has pitched blades and its
  rotation (schedule, angles, rates) seen from below; + pitch blows down turning ccw.
  One-way range = c * delay / 2, delay counted from the direct-coupling edge. SNR =
  fan-echo power (blade, wall_blade, blade_wall paths, noise-free) averaged over the
  samples inside the range gate of every pulse, over the white-noise power.

example:
  bladesonar simulate --scene config/scenes/paper-room.yaml --seconds 10 --out out/fan.wav
  bladesonar simulate --scene config/scenes/paper-room.yaml --seconds 60 --out out/rev.wav \\
      --schedule ccw:0.5:20,stop:0:5,cw:0.4:35 --snr-db 10 --drift-ppm 50 --dropouts 3
"""


def _number(what: str, lo: float | None = None, hi: float | None = None,
            lo_open: bool = False, allow_inf: bool = False) -> Callable[[str], float]:
    def conv(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number; {what}") from None
        if math.isnan(v) or (math.isinf(v) and not allow_inf):
            raise argparse.ArgumentTypeError(f"{text!r}: {what}")
        if lo is not None and (v < lo or (lo_open and v == lo)) and not math.isinf(v):
            raise argparse.ArgumentTypeError(f"{text!r}: {what}")
        if hi is not None and v > hi and not math.isinf(v):
            raise argparse.ArgumentTypeError(f"{text!r}: {what}")
        return v
    return conv


def _count(what: str, lo: int) -> Callable[[str], int]:
    def conv(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer; {what}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"{text!r}: {what}")
        return v
    return conv


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "simulate", help="render a scene (room, fan, rotation schedule) to WAV + truth JSON",
        description="Simulate the pulsed sonar in a 2-D room, or a 3-D box room with "
                    "pitched blades, with a rotating fan: writes a mono 16-bit WAV at the "
                    "config's sample rate and OUT.truth.json (per-pulse fan angle, rate, "
                    "direction, airflow in 3-D and path delays), then prints a one-line "
                    "JSON summary on stdout.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", required=True, metavar="SCENE.yaml",
                   help="scene file: room polygon, wall reflection, sensor, fan "
                        "(e.g. config/scenes/paper-room.yaml), or a 3-D box room "
                        "(config/scenes/living-room-3d.yaml)")
    p.add_argument("--seconds", required=True, metavar="S",
                   type=_number("give the length of the recording in seconds, > 0", lo=0.0,
                                lo_open=True, hi=1e7),
                   help="length of the output recording, seconds")
    p.add_argument("--out", required=True, metavar="OUT.wav",
                   help="output WAV; the truth goes to OUT.truth.json beside it "
                        "(folders are created)")
    p.add_argument("--config", metavar="CFG",
                   help="YAML config for sample rate, pri_samples, pulse shape, amplitude, "
                        "speed of sound, blade count and range gate (default: built-in "
                        "defaults: 44100 Hz, PRI 1297 samples, impulse, 4 blades)")
    _rotation_options(p)
    _impairment_options(p)
    _output_options(p)
    p.set_defaults(func=run)


def _rotation_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("rotation (default: the scene's schedule, else the config's "
                             "sim.schedule)")
    g.add_argument("--schedule", metavar="SPEC",
                   help="DIR:RATE_HZ:SECONDS,... with DIR cw, ccw or stop, e.g. "
                        "ccw:0.5:3,stop:0:2,cw:0.4:5; the last segment continues to the end")
    g.add_argument("--rate", metavar="HZ",
                   type=_number("give the fan rate in Hz (turns per second), >= 0", lo=0.0),
                   help="constant rate in Hz (turns per second); 0 = stopped")
    g.add_argument("--direction", choices=("cw", "ccw"),
                   help="direction for --rate, seen from above in the floor plan "
                        "(default: ccw)")


def _impairment_options(p: argparse.ArgumentParser) -> None:
    n = p.add_argument_group("noise and impairments")
    n.add_argument("--snr-db", metavar="DB",
                   type=_number("give the SNR in dB from -60 to 200, or inf for no noise",
                                lo=-60.0, hi=200.0, allow_inf=True),
                   help="fan-echo to noise power inside the range gate, dB (default: the "
                        "config's sim.snr_db, 20 dB); inf = no noise")
    n.add_argument("--seed", metavar="N", type=_count("give an integer >= 0", 0),
                   help="random seed for noise, start offset and drop-out positions "
                        "(default: the config's sim.seed, 1)")
    n.add_argument("--start-offset", metavar="SAMPLES",
                   type=_number("give a sample position from 0 to below pri_samples", lo=0.0),
                   help="playback sample of the first pulse, may be fractional "
                        "(default: random in the first PRI, from --seed)")
    n.add_argument("--drift-ppm", metavar="PPM", default=0.0,
                   type=_number("give a drift in ppm from -10000 to 10000", lo=-1e4, hi=1e4),
                   help="capture clock runs fast by PPM parts per million (negative: slow); "
                        "default 0")
    n.add_argument("--dropouts", metavar="N", default=0,
                   type=_count("give a number of drop-outs >= 0", 0),
                   help="number of runs of lost capture samples at random positions "
                        "(default 0)")
    n.add_argument("--dropout-samples", metavar="N", default=64,
                   type=_count("give a drop-out length of at least 1 sample", 1),
                   help="length of each drop-out, samples (default 64)")
    n.add_argument("--dropout-mode", choices=("remove", "zero"), default="remove",
                   help="remove: lost samples are missing and later ones shift earlier (an "
                        "overrun); zero: they are zeroed in place (default remove)")
    n.add_argument("--dc-offset", metavar="V", default=0.0,
                   type=_number("give a DC offset from -1 to 1 (full scale 1)", lo=-1.0, hi=1.0),
                   help="constant added to every sample, full scale = 1 (default 0)")
    n.add_argument("--clip", metavar="LEVEL",
                   type=_number("give a clip level above 0 up to 1 (full scale)", lo=0.0,
                                lo_open=True, hi=1.0),
                   help="clip samples at +-LEVEL (full scale = 1) and count them "
                        "(default: no clipping below full scale)")
    n.add_argument("--coupling-gain", metavar="G",
                   type=_number("give a gain from 0 to 1000", lo=0.0, hi=1e3),
                   help="direct speaker -> microphone gain (default: the scene's "
                        "coupling_gain); above 1 / waveform.amplitude the coupling is clipped "
                        "at the converter, as on a phone")
    n.add_argument("--nuisance", metavar="KEY=VALUE", action="append",
                   help="a real device's or room's nuisance, over the scene's nuisances: "
                        "e.g. rt60_s=0.5, agc_db=3, burst_fraction=0.1, "
                        "speaker_highpass_hz=400, speed_of_sound=346, walker_speed_m_s=1 "
                        "(repeat the option; all keys in docs/simulator.md)")


def _output_options(p: argparse.ArgumentParser) -> None:
    o = p.add_argument_group("paths and output")
    o.add_argument("--no-wall-bounces", action="store_true",
                   help="keep only the direct blade echo (plus coupling and static wall "
                        "echoes): the mirror-ambiguous case")
    o.add_argument("--no-paths", action="store_true",
                   help="omit per-pulse path lists from the truth (for very long runs)")
    o.add_argument("--quiet", action="store_true",
                   help="no progress meter and no warnings on stderr (the JSON summary is "
                        "still printed)")


def _run(args: argparse.Namespace) -> int:
    import json

    from ..io.config_file import load_config
    from ..io.scene_file import load_any_scene
    from ..io.truth import truth_path

    cfg = load_config(args.config)
    sim = _simulator(args, cfg, load_any_scene(args.scene))
    meta = sim.prepare(args.seconds)
    out = Path(args.out)
    wav, truth = _write_recording(args, cfg, sim, meta, out)
    print(json.dumps(dict(wav=str(out), truth=str(truth_path(out)), seconds=args.seconds,
                          samples=wav.frames, sample_rate=cfg.audio.sample_rate,
                          pulses=truth.pulses_written,
                          clipped_samples=sim.clipped + wav.clipped,
                          noise_sigma=sim.sigma,
                          start_offset_samples=sim.offset)))
    return 0


def _simulator(args: argparse.Namespace, cfg: Config, scene: Scene | Scene3D) -> Simulator:
    """The simulator the options describe (rotation, noise, impairments), checked against
    each other and the config."""
    import dataclasses

    from ..errors import ConfigError
    from ..sim.nuisances import parse_assignments
    from ..sim.render import Simulator
    from ..sim.schedule import Schedule, parse

    if args.rate is not None and args.schedule is not None:
        raise ConfigError("--rate", args.rate, "cannot be combined with --schedule; give one")
    if args.direction is not None and args.rate is None:
        raise ConfigError("--direction", args.direction, "needs --rate HZ (or use --schedule)")
    schedule = None
    if args.schedule is not None:
        schedule = parse(args.schedule, key="--schedule")
    if args.start_offset is not None and args.start_offset >= cfg.waveform.pri_samples:
        raise ConfigError("--start-offset", args.start_offset, "must be below pri_samples "
                          f"({cfg.waveform.pri_samples}): the first pulse starts inside the "
                          "first PRI")
    if args.rate is not None:
        schedule = Schedule.constant(args.rate, args.direction or "ccw")
    snr = cfg.sim.snr_db if args.snr_db is None else args.snr_db
    snr = None if math.isinf(snr) and snr > 0 else snr
    if snr is not None and math.isinf(snr):
        raise ConfigError("--snr-db", args.snr_db, "must be a number from -60 to 200 dB, or "
                          "inf for no noise")
    seed = cfg.sim.seed if args.seed is None else args.seed
    if args.coupling_gain is not None:
        scene = dataclasses.replace(scene, coupling_gain=float(args.coupling_gain))
    nz = parse_assignments(args.nuisance, base=scene.nuisances)
    return Simulator(scene, cfg, schedule, snr_db=snr, seed=seed, nuisances=nz,
                     start_offset=args.start_offset, drift_ppm=args.drift_ppm,
                     dropouts=args.dropouts, dropout_samples=args.dropout_samples,
                     dropout_mode=args.dropout_mode, dc_offset=args.dc_offset, clip=args.clip,
                     wall_bounces=not args.no_wall_bounces, include_paths=not args.no_paths)


def _write_recording(args: argparse.Namespace, cfg: Config, sim: Simulator, meta: dict[str, Any],
                     out: Path) -> tuple[Any, Any]:
    """The WAV and its truth sidecar, rendered chunk by chunk; both appear only when
    complete. Returns the closed writers (their counts)."""
    from ..errors import ConfigError
    from ..io.files import STALE_TEMP_S, remove_stale_temps
    from ..io.truth import TruthWriter, truth_path
    from ..io.wav import WavWriter
    from ..progress import Progress

    wav = None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        # what a killed simulate left (a write in progress refreshes its mtime)
        for q in (*remove_stale_temps(out, older_than_s=STALE_TEMP_S),
                  *remove_stale_temps(truth_path(out), older_than_s=STALE_TEMP_S)):
            logging.getLogger(__name__).info("removed %s, left by an interrupted write", q)
        wav = WavWriter(out, cfg.audio.sample_rate)
        truth = TruthWriter(truth_path(out), meta)
    except OSError as exc:
        if wav is not None:
            wav.abort()
        raise ConfigError("--out", str(args.out), f"cannot be written ({exc.strerror}); give "
                          "a writable path") from None
    fs = float(cfg.audio.sample_rate)
    prog = Progress("simulate", args.seconds, " s", enabled=False if args.quiet else None)
    done = 0
    # both files are written to hidden temporary files and renamed only when complete:
    # a full disk or an interrupt leaves neither a partial WAV nor a partial sidecar
    try:
        try:
            for x, recs in sim.chunks(args.seconds):
                wav.write(x)
                truth.write_pulses(recs)
                done += len(x)
                prog.update(done / fs)
        finally:
            prog.close()
        wav.close()
        try:
            truth.close(dict(complete=True, samples=wav.frames,
                             pulses=truth.pulses_written, clipped_samples=sim.clipped,
                             full_scale_clipped_samples=wav.clipped))
        except BaseException:
            out.unlink(missing_ok=True)
            raise
    except BaseException as exc:
        wav.abort()
        truth.abort()
        if isinstance(exc, OSError):
            raise ConfigError("--out", str(args.out), f"could not be written "
                              f"({exc.strerror or exc}); nothing was kept: free some space "
                              "or give a path on another disk") from None
        raise
    return wav, truth


def run(args: argparse.Namespace) -> int:
    # --quiet silences the simulator's warnings for this run only (the command may run
    # in-process, e.g. from tests or the report, where the logger outlives it)
    sim_log = logging.getLogger("bladesonar.sim")
    old = sim_log.level
    if args.quiet:
        sim_log.setLevel(logging.ERROR)
    try:
        return _run(args)
    finally:
        sim_log.setLevel(old)
