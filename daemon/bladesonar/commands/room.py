"""``bladesonar room``: the loopback self-test's simulated room between two ALSA FIFO PCMs."""

from __future__ import annotations

import argparse

EPILOG = """\
The room creates DIR/play.fifo, DIR/cap.fifo and DIR/asound.conf (ALSA PCMs
bladesonar_play and bladesonar_cap, no sound card needed), prints what to export, then
answers everything the daemon plays with the scene's echoes until the daemon closes its
playback (or, with --keep-serving, waits for the next session). Capture sample
latency + n answers played sample n. With --truth, one JSON line per played PRI block
gives its fan angle, phase and rate.

example (two terminals):
  bladesonar room --config cfg.yaml --scene config/scenes/paper-room.yaml \\
      --schedule ccw:0.5:60 --dir /tmp/bsroom --realtime
  export ALSA_CONFIG_PATH=/usr/share/alsa/alsa.conf:/tmp/bsroom/asound.conf
  bladesonar run --config cfg.yaml      # audio.playback_device: bladesonar_play,
                                        # audio.capture_device: bladesonar_cap
"""


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("room", help="loopback self-test: a simulated room on two ALSA FIFO "
                       "PCMs (no sound card)", description="Serve the loopback room: read "
                       "what the daemon plays through ALSA, write the scene's echoes of it "
                       "to the daemon's capture.", epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", metavar="CFG", help="the daemon's YAML config (sample rate, "
                   "PRI, format, buffer); default: built-in defaults")
    p.add_argument("--scene", metavar="SCENE", help="scene file; default: sim.scene")
    p.add_argument("--schedule", metavar="SPEC", help="rotation DIR:RATE_HZ:SECONDS,...; "
                   "default: sim.schedule")
    p.add_argument("--dir", metavar="DIR", help="folder for the FIFOs and the ALSA config "
                   "(created; needed without --pipewire)")
    p.add_argument("--pipewire", action="store_true", help="serve on the running PipeWire "
                   "graph instead: record the sink's monitor, answer into the virtual source "
                   "(both created if missing); the daemon uses audio.backend: pipewire")
    p.add_argument("--sink", default="bladesonar_sink", metavar="NODE",
                   help="--pipewire: the sink the daemon plays into (default %(default)s)")
    p.add_argument("--source", default="bladesonar_source", metavar="NODE",
                   help="--pipewire: the virtual source the daemon records (default "
                   "%(default)s)")
    p.add_argument("--realtime", action="store_true", help="pace the capture at the sample "
                   "rate (default: as fast as the daemon reads)")
    p.add_argument("--latency", type=int, metavar="SAMPLES", help="capture delay of the "
                   "room's answer; default: one ALSA buffer + 321")
    p.add_argument("--noise", type=float, default=0.0, metavar="SIGMA",
                   help="white noise on the capture, full scale = 1 (default 0)")
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    p.add_argument("--truth", metavar="FILE.jsonl", help="write each played block's fan angle")
    p.add_argument("--connect-timeout", type=float, metavar="S",
                   help="give up if no daemon connects within S seconds")
    p.add_argument("--seconds", type=float, metavar="S", help="end a session after S seconds")
    p.add_argument("--keep-serving", action="store_true",
                   help="after the daemon closes, wait for it to open again")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys
    from pathlib import Path

    from ..errors import InputError
    from ..io.config_file import load_config
    from ..io.scene_file import load_scene
    from ..loopback import CAP_PCM, PLAY_PCM, Room, write_alsa_config

    cfg = load_config(args.config)
    scene = load_scene(args.scene or cfg.path(cfg.sim.scene))
    if args.pipewire:
        return _run_pipewire(args, cfg, scene)
    if not args.dir:
        raise InputError("--dir DIR is needed (the FIFOs and the ALSA config go there), "
                         "or --pipewire")
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    fifo_play, fifo_cap = d / "play.fifo", d / "cap.fifo"
    env = write_alsa_config(d / "asound.conf", fifo_play, fifo_cap)
    stop = _stop_on_signals()
    truth = open(args.truth, "w", encoding="utf-8") if args.truth else None
    sessions = 0
    try:
        while not stop["now"]:
            room = Room(scene, cfg, args.schedule or cfg.sim.schedule, fifo_play=fifo_play,
                        fifo_cap=fifo_cap, realtime=args.realtime,
                        latency_samples=args.latency, noise_sigma=args.noise, seed=args.seed,
                        truth=truth)
            room.open()
            if sessions == 0:
                for k, v in env.items():
                    print(f"export {k}={v}")
                print(f"playback_device: {PLAY_PCM}\ncapture_device: {CAP_PCM}\n"
                      f"format: {cfg.audio.format}  rate: {cfg.audio.sample_rate}  "
                      f"pri_samples: {cfg.waveform.pri_samples}  latency: {room.latency}")
                print("ready", flush=True)
            try:
                st = room.serve(connect_timeout=args.connect_timeout,
                                max_seconds=args.seconds, should_stop=lambda: stop["now"])
            finally:
                room.close()
            sessions += 1
            print(f"session {sessions}: {st.periods_played} periods played, "
                  f"{st.periods_captured} captured, {st.seconds:.2f} s, ended: {st.ended_by}",
                  file=sys.stderr, flush=True)
            if not args.keep_serving or st.ended_by in ("no daemon", "stopped"):
                break
    finally:
        if truth is not None:
            truth.close()
    return 0


def _run_pipewire(args: argparse.Namespace, cfg: object, scene: object) -> int:
    import sys

    from ..loopback.pw_room import PwRoom

    stop = _stop_on_signals()
    truth = open(args.truth, "w", encoding="utf-8") if args.truth else None
    room = PwRoom(scene, cfg, args.schedule or cfg.sim.schedule,  # type: ignore[attr-defined]
                  sink=args.sink, source=args.source, noise_sigma=args.noise, seed=args.seed,
                  truth=truth)
    try:
        room.open()
        print(f"playback_device: {room.sink}\ncapture_device: {room.source}\n"
              f"format: {room.fmt}  rate: {int(room.fs)}  pri_samples: {room.pri}  "
              f"latency: {room.prime + room.latency} + the graph's")
        print("ready", flush=True)
        st = room.serve(max_seconds=args.seconds, should_stop=lambda: stop["now"])
    finally:
        room.close()
        if truth is not None:
            truth.close()
    print(f"{room.sessions} sessions, {st.periods_played} blocks answered, "
          f"{room.reconnects} reconnects, ended: {st.ended_by}", file=sys.stderr, flush=True)
    return 0


def _stop_on_signals() -> dict[str, bool]:
    """A flag that SIGTERM and SIGINT set: the room's loops end at their next period."""
    import signal

    stop = {"now": False}

    def on_signal(*_: object) -> None:
        stop["now"] = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    return stop
