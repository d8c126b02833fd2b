"""The loopback room on a PipeWire graph: the daemon's PipeWire path with no sound card.

The graph holds two null nodes (no hardware; a Dummy-Driver clocks them in real time): a
sink the daemon plays into and a virtual source it records from. The room captures the
sink's monitor, renders the scene's echoes of each PRI-sized block at the fan angle of
that moment (the same echo model as the FIFO room, ``Room._answer``), and plays the
result into the virtual source. Every sample read gives one sample written, so the
room is a fixed delay line on the graph's clock; the daemon's aligner finds the
direct-coupling edge as on a card. Its streams lock the quantum (``node.lock-quantum``):
a quantum forced from outside still changes the graph's, but the room's delay stays
where it was, as air's would (docs/audio.md, "A quantum change").

A virtual source takes no automatic links from the session manager (streams are only
linked to sinks), so the room's playback stream is created with ``node.autoconnect =
false`` and linked to the source's input port with ``pw-link``. The schedule starts when
the daemon's first pulse arrives and starts again after half a second of silence (the
next session: a reference, then the daemon), or after the graph stalled for as long.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ..errors import AudioDeviceError
from ..service import sound_server
from ..service.audio import decode, encode
from ..service.pipewire_audio import stream_props_text
from .room import Room

log = logging.getLogger(__name__)

SINK = "bladesonar_sink"
#: Both null nodes and the room's streams are scheduled as one group, under one driver,
#: whoever else joins the graph
GROUP = "bladesonar-room"
SOURCE = "bladesonar_source"
#: The room's own ALSA period (samples) and buffer (periods): deep, so that a busy
#: machine does not starve the room's playback (an underrun would shift its delay).
ROOM_PERIOD = 1024
ROOM_PERIODS = 16
#: A gap of this much silence from the daemon ends a session.
SESSION_GAP_S = 0.5
#: How long the room waits for a (re)started server and its nodes.
WAIT_S = 20.0


def node_commands(sink: str = SINK, source: str = SOURCE) -> list[list[str]]:
    """``pw-cli`` commands that create the room's two null nodes (mono, lingering)."""
    return [["pw-cli", "create-node", "adapter",
             f"{{ factory.name=support.null-audio-sink node.name={name} media.class={cls} "
             f"object.linger=true audio.position=[MONO] node.group={GROUP} }}"]
            for name, cls in ((sink, "Audio/Sink"), (source, "Audio/Source/Virtual"))]


class PwRoom(Room):
    """One room on the graph for as long as it runs (sessions follow the daemon's sound)."""

    def __init__(self, scene: Any, cfg: Any, schedule: Any = None, *, sink: str = SINK,
                 source: str = SOURCE, noise_sigma: float = 0.0, seed: int = 0,
                 truth: Any = None, extra_latency: int = 321) -> None:
        buffer = cfg.audio.buffer_periods * cfg.audio.period_pulses * cfg.waveform.pri_samples
        super().__init__(scene, cfg, schedule, fifo_play="-", fifo_cap="-",
                         latency_samples=buffer, noise_sigma=noise_sigma, seed=seed,
                         truth=truth)
        self.sink, self.source = sink, source
        # the room's output runs ``prime`` samples behind its input; an echo goes out
        # ``latency`` samples after the block it answers began: a whole PRI block is read
        # before it is answered, and what was read before it was already written
        self.prime = ROOM_PERIODS // 2 * ROOM_PERIOD
        self.latency = self.pri + ROOM_PERIOD + int(extra_latency)
        self._cap: Any = None
        self._play: Any = None
        self.sessions = 0
        self.reconnects = 0
        self._underruns = 0
        self._in_session = False

    # -- the graph side ------------------------------------------------------------------

    def _pcm(self, alsa: Any, kind: str, node: str, props: dict[str, str]) -> Any:
        os.environ["PIPEWIRE_PROPS"] = stream_props_text(props)
        fmt = getattr(alsa, f"PCM_FORMAT_{self.fmt}")
        return alsa.PCM(type=alsa.PCM_CAPTURE if kind == "capture" else alsa.PCM_PLAYBACK,
                        mode=alsa.PCM_NORMAL, device=f"pipewire:NODE={node}",
                        rate=int(self.fs), channels=1, format=fmt, periodsize=ROOM_PERIOD,
                        periods=ROOM_PERIODS)

    def open(self) -> None:
        from ..service.alsa_audio import _alsaaudio

        alsa = _alsaaudio()
        deadline = time.monotonic() + WAIT_S
        while sound_server.detect().kind != "pipewire":
            if time.monotonic() > deadline:
                raise AudioDeviceError("the room found no PipeWire server")
            time.sleep(0.2)
        self._ensure_nodes(deadline)
        # node.lock-quantum: measured with tools/pw_quantum_probe, without it the room's
        # own delay on the graph dropped by the difference when the quantum went back
        # up (1024 -> 256 -> 1024: -768 samples, 5 of 5 runs; air does not re-buffer),
        # with it the delay stayed put through both changes (6 of 6)
        base = {"node.dont-reconnect": "true", "application.name": "bladesonar-room",
                "node.group": GROUP, "node.lock-quantum": "true",
                # tools/pw_quantum_probe --room-props: properties tried on the room's streams
                **json.loads(os.environ.get("ROOM_EXTRA_PROPS") or "{}")}
        self._cap = self._pcm(alsa, "capture", self.sink,
                              {**base, "stream.capture.sink": "true",
                               "node.name": "bladesonar-room-in"})
        self._play = self._pcm(alsa, "playback", self.source,
                               {**base, "node.autoconnect": "false",
                                "node.name": "bladesonar-room-out"})
        os.environ.pop("PIPEWIRE_PROPS", None)
        self._link(deadline)
        self._acc_start = 0
        self._acc = np.zeros(self.prime)
        self._write(self.prime)

    def _ensure_nodes(self, deadline: float) -> None:
        """Create the sink and the virtual source unless the graph has them."""
        while True:
            dump = sound_server.pw_dump()
            names = {((o.get("info") or {}).get("props") or {}).get("node.name")
                     for o in dump or []}
            todo = [c for c, name in zip(node_commands(self.sink, self.source),
                                         (self.sink, self.source), strict=True)
                    if name not in names]
            if dump is not None and not todo:
                return
            if time.monotonic() > deadline:
                raise AudioDeviceError(f"cannot create the nodes {self.sink}, {self.source} "
                                       "(pw-cli create-node failed)")
            for cmd in todo if dump is not None else []:
                subprocess.run(cmd, capture_output=True, timeout=10, check=False)
            time.sleep(0.2)

    def _link(self, deadline: float) -> None:
        """Link the room's playback to the virtual source (pw-link, retried while the
        stream or the node is still being created)."""
        exe = shutil.which("pw-link") or "pw-link"
        err = ""
        while time.monotonic() < deadline:
            r = subprocess.run([exe, "bladesonar-room-out:output_MONO",
                                f"{self.source}:input_MONO"], capture_output=True, text=True,
                               timeout=10, check=False)
            if r.returncode == 0 or "exists" in r.stderr.lower():
                return
            err = r.stderr.strip()
            time.sleep(0.2)
        raise AudioDeviceError(f"pw-link to {self.source} failed: {err}")

    def close(self) -> None:
        for name in ("_play", "_cap"):
            pcm = getattr(self, name, None)
            if pcm is not None:
                try:
                    pcm.close()
                except Exception:  # noqa: BLE001 - a dead server: nothing to close
                    pass
                setattr(self, name, None)

    def _write(self, n: int) -> None:
        x = self._acc[:n]
        if self.noise_sigma > 0:
            x = x + self._noise(self._acc_start, n)
        got = self._play.write(encode(x, self.fmt))
        if got < 0:
            self._underruns += 1
            if self._underruns >= 20:
                raise AudioDeviceError("room playback: the server is gone")
            log.warning("room playback underrun")
        else:
            self._underruns = 0
        self._acc = self._acc[n:]
        self._acc_start += n
        self.stats.periods_captured += 1

    # -- the session ---------------------------------------------------------------------

    def serve(self, *, connect_timeout: float | None = None, max_seconds: float | None = None,
              should_stop: Callable[[], bool] = lambda: False) -> Any:
        """Answer until stopped; a lost server is waited for and the room reconnects."""
        while not should_stop():
            try:
                self._serve_connected(should_stop, max_seconds)
                break
            except (AudioDeviceError, self._alsa_error()) as exc:   # the server went away
                if should_stop():
                    break
                log.warning("room lost the graph (%s); reconnecting", exc)
                self._truth_session_end()
                self.close()
                self.reconnects += 1
                time.sleep(0.5)
                self.open()
        self.stats.ended_by = self.stats.ended_by or "stopped"
        return self.stats

    def _truth_session_end(self) -> None:
        """A truth line when a session ends: a test starts the next daemon only after it
        (a daemon started sooner, while the room still waited out the gap, was taken for
        the last one's session going on, on the last one's schedule)."""
        if self.truth is not None and self._in_session:
            self.truth.write(json.dumps({"session_ended_at": time.time()}) + "\n")
            self.truth.flush()
        self._in_session = False

    @staticmethod
    def _alsa_error() -> type[Exception]:
        from ..service.alsa_audio import _alsaaudio

        error: type[Exception] = _alsaaudio().ALSAAudioError   # the module is untyped (Any)
        return error

    def _serve_connected(self, should_stop: Callable[[], bool],
                         max_seconds: float | None) -> None:
        pri = self.pri
        cin = 0                  # capture-stream index of the next sample read
        block = np.zeros(0)
        block_at = 0             # capture-stream index of block[0]
        k = 0                    # PRI blocks since the session began
        silent = 0               # consecutive silent samples
        gap = int(SESSION_GAP_S * self.fs)
        active = False
        overruns = 0             # in a row
        t_start = time.monotonic()
        while not should_stop():
            if max_seconds is not None and time.monotonic() - t_start > max_seconds:
                self.stats.ended_by = "time limit"
                return
            t_read = time.monotonic()
            n, data = self._cap.read()
            if active and time.monotonic() - t_read > SESSION_GAP_S:
                # the graph stopped (a suspended node): the daemon's next sound is a new
                # session, as after silence
                active, block = False, np.zeros(0)
                log.info("session %d ended (the graph stalled)", self.sessions)
                self._truth_session_end()
            if n < 0:
                if n != -32:
                    raise AudioDeviceError(f"room capture failed with error {n}")
                overruns += 1
                if overruns >= 20:       # every read fails at once: the server is gone
                    raise AudioDeviceError("room capture: the server is gone")
                log.warning("room capture overrun")
                continue
            overruns = 0
            x = decode(data, self.fmt)
            pos, cin = cin, cin + len(x)
            loud = np.flatnonzero(np.abs(x) > 1e-4)
            if not active and len(loud):
                active, k, self.sessions = True, 0, self.sessions + 1
                block, block_at = x[loud[0]:], pos + int(loud[0])   # pulse 0: schedule t=0
                self._noise_origin = block_at + self.prime + self.latency
                self._t0 = time.monotonic()
                log.info("session %d: the daemon plays", self.sessions)
                self._truth_session((self.prime + self.latency) / self.fs)
                self._in_session = True
            elif active:
                block = np.concatenate([block, x])
            silent = silent + len(x) if not len(loud) else len(x) - 1 - int(loud[-1])
            if active and silent > gap:
                active, block = False, np.zeros(0)
                log.info("session %d ended (silence)", self.sessions)
                self._truth_session_end()
            while len(block) >= pri:
                self._answer(k, block[:pri], at_sample=block_at + self.prime + self.latency)
                self.stats.periods_played += 1
                block, block_at, k = block[pri:], block_at + pri, k + 1
            # one sample out per sample in: the answer is a fixed delay on the graph clock
            if len(self._acc) < len(x):
                self._acc = np.concatenate([self._acc, np.zeros(len(x) - len(self._acc))])
            self._write(len(x))
