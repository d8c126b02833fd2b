"""``bladesonar plot KIND``: the paper's pictures from a recording (or a scene), PNG or SVG.

A thin edge: read files, call :mod:`bladesonar.imaging` for the numbers and
:mod:`bladesonar.plots` (matplotlib, the ``plots`` extra) for the drawing.
"""

from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from ..config import Config
    from ..dsp.gate import Gate

#: The number type an option converts its text to (``_positive``).
_Num = TypeVar("_Num", int, float)

#: Most rows and longest row `plot track` reads (memory bounded).
MAX_ROWS = 500_000
MAX_ROW_CHARS = 16_384

EPILOG = """\
kinds:
  rd      range-doppler map (dB): doppler in Hz against one-way range, the analysis gate marked
  isar    backprojected image in the frame turning with the fan (needs the rate and geometry)
  matrix  pulse-to-pulse matching distance of two recordings; stripe slope = rate ratio
  track   the filtered angular fingerprint of 'analyze --track' rows, decisions, reversals
  sim     simulated multipath ranges against pulse number, ccw solid and cw dashed
  airflow the moving echoes' envelopes against time and range (static removed): the glint
          streaks, falling for a down-draft and rising for an up-draft, and the slope the
          airflow stage measured (no reference needed)

One-way range = c * delay / 2, delay counted from the direct-coupling edge. The format comes
from the --out suffix (.png or .svg). Needs matplotlib: pip install 'bladesonar[plots]'.

examples:
  bladesonar plot rd --out rd.png fan.wav
  bladesonar plot isar --scene config/scenes/paper-room.yaml --rate 0.5 --out isar.png fan.wav
  bladesonar plot matrix --out m.png reference.wav probe.wav
  bladesonar analyze --reference ref.npz --track probe.wav > t.jsonl
  bladesonar plot track --truth probe.truth.json --out track.png t.jsonl
  bladesonar plot sim --scene config/scenes/paper-room.yaml --out sim.png
  bladesonar plot airflow --seconds 3 --max-range 3 --out airflow.png fan.wav
"""


def _point(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give a point as X,Y in metres, "
                                         "e.g. 0.5,0.6") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise argparse.ArgumentTypeError(f"{text!r}: coordinates must be finite")
    return x, y


def _positive(kind: Callable[[str], _Num], what: str) -> Callable[[str], _Num]:
    def conv(text: str) -> _Num:
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number; {what}") from None
        if not (v > 0 and math.isfinite(v)):
            raise argparse.ArgumentTypeError(f"{text!r}: {what}")
        return v
    return conv


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("plot", help="pictures: range-doppler, ISAR, distance matrix, track, "
                       "simulated paths (PNG/SVG)",
                       description="Draw the paper's pictures from a recording or a scene.",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    kinds = p.add_subparsers(dest="kind", metavar="KIND", required=True)
    for add in (_rd_options, _isar_options, _matrix_options, _track_options,
                _sim_options, _airflow_options):
        _common(add(kinds))


def _common(q: argparse.ArgumentParser, config: bool = True) -> None:
    """The options every kind of picture has."""
    q.add_argument("--out", required=True, metavar="FILE.png|.svg",
                   help="picture to write; the format follows the suffix")
    if config:
        q.add_argument("--config", metavar="CFG",
                       help="YAML config (default: built-in defaults)")
    q.add_argument("--title", help="title instead of the default one")
    q.set_defaults(func=run)


def _rd_options(kinds: argparse._SubParsersAction[argparse.ArgumentParser]
                ) -> argparse.ArgumentParser:
    q = kinds.add_parser("rd", help="range-doppler map of a recording")
    q.add_argument("wav", metavar="IN.wav")
    q.add_argument("--reference", metavar="REF", help="mark this reference's gate (default: "
                   "the gate the config, or the target found in this recording, gives)")
    q.add_argument("--pulses", type=_positive(int, "give a number of pulses > 0"),
                   help="use the first N usable pulses (default: all)")
    q.add_argument("--max-range", type=_positive(float, "give a range in m > 0"),
                   metavar="M", help="top of the range axis, m (default: one PRI)")
    q.add_argument("--floor-db", type=float,
                   help="colour floor, dB (default: 3 dB over the map's median noise floor)")
    return q


def _isar_options(kinds: argparse._SubParsersAction[argparse.ArgumentParser]
                  ) -> argparse.ArgumentParser:
    q = kinds.add_parser("isar", help="ISAR image in the fan's rotating frame")
    q.add_argument("wav", metavar="IN.wav")
    src = q.add_mutually_exclusive_group(required=True)
    src.add_argument("--reference", metavar="REF",
                     help="take the rate and direction from this reference")
    src.add_argument("--rate", type=_positive(float, "give the fan rate in Hz > 0"),
                     metavar="HZ", help="fan rate, turns per second")
    q.add_argument("--direction", choices=("cw", "ccw"),
                   help="direction for --rate (default ccw) or for a reference that does "
                        "not know its own")
    q.add_argument("--scene", metavar="SCENE.yaml",
                   help="sensor, fan centre, blade circle and start angle from a scene file")
    q.add_argument("--sensor", type=_point, metavar="X,Y", help="sensor position, m")
    q.add_argument("--centre", type=_point, metavar="X,Y", help="fan centre, m")
    q.add_argument("--start-angle-deg", type=float,
                   help="fan angle at the recording's start (default: the scene's, else 0; "
                        "an error only rotates the image)")
    q.add_argument("--extent", type=_positive(float, "give a half width in m > 0"),
                   metavar="M", help="image half width, m (default: blade tip + 0.25, else 1)")
    q.add_argument("--pixels", type=_positive(int, "give a pixel count > 0"), default=256)
    q.add_argument("--pulses", type=_positive(int, "give a number of pulses > 0"),
                   default=175, help="pulses backprojected (default 175, the paper's)")
    q.add_argument("--start-pulse", type=int, default=0, help="first usable pulse used")
    q.add_argument("--mode", choices=("envelope", "coherent"), default="envelope",
                   help="sum envelopes (default, robust) or analytic samples (sharper)")
    q.add_argument("--floor-db", type=float, default=-20.0, help="colour floor (default -20)")
    return q


def _matrix_options(kinds: argparse._SubParsersAction[argparse.ArgumentParser]
                    ) -> argparse.ArgumentParser:
    q = kinds.add_parser("matrix", help="pairwise matching distance of two recordings")
    q.add_argument("wav_a", metavar="A.wav", help="rows (e.g. the reference recording)")
    q.add_argument("wav_b", metavar="B.wav", nargs="?",
                   help="columns (default: A against itself)")
    q.add_argument("--reference", metavar="REF",
                   help="use this reference's gate (default: as the config, or found in A)")
    q.add_argument("--pulses", type=_positive(int, "give a number of pulses > 0"),
                   default=175, help="pulses of each recording (default 175)")
    q.add_argument("--plain", action="store_true",
                   help="show the plain distance (default: row and column means removed, "
                        "which makes the stripes stand out)")
    return q


def _track_options(kinds: argparse._SubParsersAction[argparse.ArgumentParser]
                   ) -> argparse.ArgumentParser:
    q = kinds.add_parser("track", help="the angular fingerprint track of analyze --track rows")
    q.add_argument("rows", metavar="ROWS.jsonl", help="output of 'bladesonar analyze --track' "
                   "('-' = standard input)")
    q.add_argument("--truth", metavar="TRUTH.json",
                   help="simulator truth: mark the true reversals")
    return q


def _sim_options(kinds: argparse._SubParsersAction[argparse.ArgumentParser]
                 ) -> argparse.ArgumentParser:
    q = kinds.add_parser("sim", help="simulated multipath ranges, ccw vs cw")
    q.add_argument("--scene", required=True, metavar="SCENE.yaml")
    q.add_argument("--rate", type=_positive(float, "give the fan rate in Hz > 0"),
                   default=0.5, metavar="HZ", help="fan rate (default 0.5)")
    q.add_argument("--pulses", type=_positive(int, "give a number of pulses > 0"),
                   default=175, help="pulses (default 175)")
    q.add_argument("--direct", action="store_true", help="also draw the direct blade echoes")
    return q


def _airflow_options(kinds: argparse._SubParsersAction[argparse.ArgumentParser]
                     ) -> argparse.ArgumentParser:
    q = kinds.add_parser("airflow", help="range-time picture of the moving echoes: the "
                         "glint streaks and their slope")
    q.add_argument("wav", metavar="IN.wav")
    q.add_argument("--start", type=float, default=0.0, metavar="S",
                   help="first second shown (default 0)")
    q.add_argument("--seconds", type=_positive(float, "give a duration in s > 0"),
                   default=4.0, metavar="S", help="seconds shown (default 4; the airflow "
                   "is measured on the whole recording, its first 23.8 s at most)")
    q.add_argument("--max-range", type=_positive(float, "give a range in m > 0"),
                   metavar="M", help="top of the range axis, m (default: the gate's end)")
    return q


def run(args: argparse.Namespace) -> int:
    from ..plots import out_format

    out_format(args.out)  # refuse a bad suffix before any work
    from .. import plots

    plots.pyplot()  # and a missing matplotlib
    fn = {"rd": _rd, "isar": _isar, "matrix": _matrix, "track": _track, "sim": _sim,
          "airflow": _airflow}
    path = fn[args.kind](args)
    print(str(path))
    return 0


def _cfg(args: argparse.Namespace) -> Config:
    from ..io.config_file import load_config

    return load_config(getattr(args, "config", None))


def _ref_gate(args: argparse.Namespace, cfg: Config) -> Gate | None:
    if not getattr(args, "reference", None):
        return None
    from ..io.reference import load_reference
    from ..reference_build import check_compatible

    ref = load_reference(args.reference)
    check_compatible(ref, cfg)
    return ref.gate


def _rd(args: argparse.Namespace) -> Path:
    from .. import imaging
    from ..io.wav import read_wav
    from ..plots import rd

    cfg = _cfg(args)
    x, _ = read_wav(args.wav, expect_rate=cfg.audio.sample_rate)
    m = imaging.rd_map(x, cfg, max_pulses=args.pulses, ref_gate=_ref_gate(args, cfg))
    return rd.draw(m, args.out, title=args.title or "", floor_db=args.floor_db,
                   max_range_m=args.max_range)


def _isar(args: argparse.Namespace) -> Path:
    from .. import imaging
    from ..errors import ConfigError
    from ..io.wav import read_wav
    from ..plots import isar

    cfg = _cfg(args)
    x, _ = read_wav(args.wav, expect_rate=cfg.audio.sample_rate)
    scene = None
    if args.scene:
        from ..io.scene_file import load_scene

        scene = load_scene(args.scene).with_config(cfg)
    sensor = args.sensor or (scene.sensor if scene else None)
    centre = args.centre or (scene.fan_centre if scene else None)
    if sensor is None or centre is None:
        raise ConfigError("--scene", None, "the image needs the sensor and the fan centre: give "
                          "--scene SCENE.yaml or both --sensor X,Y and --centre X,Y")
    if args.reference:
        from ..io.reference import load_reference

        ref = load_reference(args.reference)
        rate = float(ref.meta["rate_hz"])
        direction = args.direction or ref.meta.get("direction")
        if direction not in ("cw", "ccw"):
            raise ConfigError("--direction", None, "the reference does not know its direction; "
                              "give --direction cw or ccw (a wrong one only mirrors the image)")
    else:
        rate, direction = args.rate, args.direction or "ccw"
    signed = rate if direction == "ccw" else -rate
    start = (math.radians(args.start_angle_deg) if args.start_angle_deg is not None
             else (scene.start_angle_rad if scene else 0.0))
    extent = args.extent or ((scene.tip_radius_m + 0.25) if scene else 1.0)
    ap = imaging.aligned(x, cfg)
    p, e = imaging.valid_pulses(ap, args.pulses, args.start_pulse)
    img = imaging.backproject(p - p.mean(axis=0), e / cfg.audio.sample_rate, delay0=0.0,
                              fs=cfg.audio.sample_rate, c=cfg.scene.speed_of_sound,
                              sensor=sensor, centre=centre, rate_hz=signed, start_rad=start,
                              extent_m=extent, n_pix=args.pixels, mode=args.mode)
    return isar.draw(img, args.out, title=args.title or "", floor_db=args.floor_db,
                     tip_m=scene.tip_radius_m if scene else None,
                     hub_m=scene.hub_radius_m if scene and scene.hub_radius_m > 0 else None)


def _matrix(args: argparse.Namespace) -> Path:
    from pathlib import Path

    from .. import imaging
    from ..io.wav import read_wav
    from ..plots import matrix

    cfg = _cfg(args)
    xa, _ = read_wav(args.wav_a, expect_rate=cfg.audio.sample_rate)
    gate = _ref_gate(args, cfg)
    if gate is None:
        gate = imaging.rd_map(xa, cfg).gate
    pa, _ = imaging.valid_pulses(imaging.aligned(xa, cfg, gate), args.pulses)
    fa = imaging.features(pa, cfg)
    if args.wav_b:
        xb, _ = read_wav(args.wav_b, expect_rate=cfg.audio.sample_rate)
        pb, _ = imaging.valid_pulses(imaging.aligned(xb, cfg, gate), args.pulses)
        fb = imaging.features(pb, cfg)
    else:
        fb = fa
    d = imaging.distance_matrix(fa, fb)
    try:
        st = imaging.stripe_slope(d)
    except ValueError:
        st = None
    la = Path(args.wav_a).stem
    lb = Path(args.wav_b).stem if args.wav_b else la
    return matrix.draw(d, cfg.prf_hz, args.out, stripes=st, label_a=la, label_b=lb,
                       title=args.title or "", centred=not args.plain)


def _track(args: argparse.Namespace) -> Path:
    import json
    import sys

    from .. import imaging
    from ..errors import InputError
    from ..plots import track

    cfg = _cfg(args)
    try:
        f = sys.stdin if args.rows == "-" else open(args.rows, encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{args.rows}: cannot be read ({exc.strerror})") from exc
    rows = []
    with f:
        for n, line in enumerate(f, 1):
            # bounded: an hour of pulses is 122 400 rows of a few hundred characters
            if n > MAX_ROWS or len(line) > MAX_ROW_CHARS:
                raise InputError(f"{args.rows}:{n}: more than {MAX_ROWS} rows or a row over "
                                 f"{MAX_ROW_CHARS} characters; cut it, e.g. 'head -n "
                                 f"{MAX_ROWS} {args.rows} > part.jsonl'")
            if line.strip():
                try:
                    rows.append(json.loads(line))
                except json.JSONDecodeError as exc:
                    raise InputError(f"{args.rows}:{n}: not a JSON line ({exc.msg}); give the "
                                     "output of 'bladesonar analyze --track'") from exc
    s = imaging.track_series(rows)
    true_rev: list[float] = []
    if args.truth:
        from ..io.truth import read_truth

        try:
            meta = read_truth(args.truth)["meta"]
        except (OSError, ValueError, KeyError) as exc:
            raise InputError(f"{args.truth}: not a simulator truth file ({exc})") from exc
        true_rev = list(imaging.reversal_times(meta["schedule"]))
    return track.draw(s, args.out, title=args.title or "",
                      min_confidence=cfg.tracking.min_confidence, true_reversals=true_rev)


def _sim(args: argparse.Namespace) -> Path:
    from .. import imaging
    from ..io.scene_file import load_scene
    from ..plots import sim

    cfg = _cfg(args)
    scene = load_scene(args.scene).with_config(cfg)
    ccw = imaging.path_ranges(scene, cfg, args.rate, args.pulses)
    cw = imaging.path_ranges(scene, cfg, -args.rate, args.pulses)
    dc = dw = None
    if args.direct:
        dc = imaging.path_ranges(scene, cfg, args.rate, args.pulses, kinds=("blade",))
        dw = imaging.path_ranges(scene, cfg, -args.rate, args.pulses, kinds=("blade",))
    title = args.title or (f"{scene.name}: simulated multipath echoes at {args.rate:g} Hz, "
                           "solid ccw, dashed cw")
    return sim.draw(ccw, cw, args.out, title=title, direct_ccw=dc, direct_cw=dw)


def _airflow(args: argparse.Namespace) -> Path:
    from ..airflow_recording import range_time
    from ..io.wav import read_wav
    from ..plots import airflow
    from .analyze import AIRFLOW_SAMPLES

    cfg = _cfg(args)
    x, _ = read_wav(args.wav, expect_rate=cfg.audio.sample_rate,
                    max_samples=AIRFLOW_SAMPLES, cut=True)
    rt = range_time(x, cfg, start_s=args.start, seconds=args.seconds)
    return airflow.draw(rt, args.out, title=args.title or "", max_range_m=args.max_range)
