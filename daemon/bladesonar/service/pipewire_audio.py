"""PipeWire backend: the ALSA backend's two threads on PipeWire's ALSA plugin PCM.

Why the plugin and not pw-cat or a native binding: it keeps the ALSA path's tested code
(the global sample counter, whole-period reads, xrun handling) and needs no new Python
package, and measured on the headless graph it delivers sample-exact periods at the
graph's clock (docs/audio.md). Both streams belong to one graph, so they share its clock
and sample grid; the backend makes sure nothing is resampled (our rate must be the
graph's) and asks, through the stream properties, that the server neither moves, pauses
nor suspends our streams. Echo cancellation, AGC and noise suppression in PipeWire are
filter nodes (module-echo-cancel), not stream properties: a stream linked to the device
node directly never passes through them, and the backend says when a stream of ours
would go to such a filter.
"""

from __future__ import annotations

import logging
import os
import re
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from ..dsp.pulses import coupling_peak
from ..errors import AudioDeviceError
from . import sound_server
from .alsa_audio import AlsaAudio, _alsaaudio
from .audio import PulseBlock

if TYPE_CHECKING:
    from ..config import Config

log = logging.getLogger(__name__)

#: Properties of our two streams (``PIPEWIRE_PROPS``, read by libpipewire whenever the
#: ALSA plugin creates a stream). ``node.dont-reconnect``: never moved to another device
#: (a vanished device stalls the capture and the daemon reopens it); the two ``pause``/
#: ``always-process`` keys keep the streams and so the device running; the role keeps
#: phone policies (which route "Communication"/"Phone" streams through echo-cancel) away.
STREAM_PROPS = {
    "node.dont-reconnect": "true",
    "node.pause-on-idle": "false",
    "node.always-process": "true",
    "node.want-driver": "true",
    "media.role": "Production",
    "media.category": "Duplex",
    "stream.dont-remix": "true",
    "application.name": "bladesonar",
}

#: How long start() waits for a server that is (re)starting.
CONNECT_WAIT_S = 8.0
#: Seconds without a direct-coupling pulse (after they came back once) that mean the
#: graph stopped carrying the streams (a suspended node): then they are reopened.
SILENT_S = 3.0

_NODE_NAME = re.compile(r"^[A-Za-z0-9_.:@+-]+$")


def stream_props_text(props: dict[str, str] | None = None) -> str:
    """``STREAM_PROPS`` as SPA JSON for ``PIPEWIRE_PROPS``."""
    items = (props or STREAM_PROPS).items()
    return "{ " + " ".join(f'{k} = "{v}"' for k, v in items) + " }"


def pcm_name(node: str, key: str) -> str:
    """The ALSA PCM name that reaches PipeWire node ``node`` (``default``: the server's
    default sink or source)."""
    if node in ("default", "pipewire", ""):
        return "pipewire"
    if not _NODE_NAME.match(node):
        raise AudioDeviceError(f"audio.{key} {node!r}: a PipeWire node name (see `pw-cli ls "
                               "Node` or `wpctl status`) of letters, digits and _.:@+-, or "
                               "'default'")
    return f"pipewire:NODE={node}"


class StreamLatency:
    """The latency between the two streams, in samples, followed pulse by pulse.

    Pulse k leaves at played sample k * pri, and capture starts before the first pulse
    can come back, so the first direct-coupling peak's capture index is the whole latency
    (path plus the start offset of the two streams). After that, the peak's place within
    each PRI is followed wrap-aware, like clock drift: a change of more than ``JUMP``
    samples between pulses is a latency jump (a server that re-buffered, a restart) and
    is counted. A coarse figure (to a sample) for stats; the aligner times the edge to a
    hundredth of a sample on its own.
    """

    JUMP = 2
    #: consecutive PRIs whose peaks sit at one place before the first is believed (a
    #: noise peak does not repeat)
    LOCK = 3

    def __init__(self, pri: int) -> None:
        self.pri = int(pri)
        self.samples: int | None = None
        self.first: int | None = None
        self.lo: int | None = None
        self.hi: int | None = None
        self.jumps = 0
        self._pos: int | None = None         # peak index within the PRI, last pulse
        self._cand: list[tuple[int, int]] = []    # (PRI start, peak place) before a lock

    def push(self, x: np.ndarray, start_sample: int, discontinuity: bool = False) -> bool:
        """Follow one PRI of capture; whether it held a coupling peak."""
        i = coupling_peak(np.abs(x))
        if i is None:
            if self.samples is None:
                self._cand.clear()
            return False
        if self.samples is None:
            if self._cand:
                at, place = self._cand[-1]
                if start_sample != at + self.pri or abs(i - place) > self.JUMP:
                    self._cand.clear()
            self._cand.append((start_sample, i))
            if len(self._cand) < self.LOCK:
                return True
            at, place = self._cand[0]
            self.first = at + place
            self.samples = self.first + (i - place)
            self._cand.clear()
        else:
            assert self._pos is not None
            d = (i - self._pos + self.pri // 2) % self.pri - self.pri // 2
            if abs(d) > self.JUMP or discontinuity:
                self.jumps += 1
            self.samples += d
        self._pos = i
        self.lo = self.samples if self.lo is None else min(self.lo, self.samples)
        self.hi = self.samples if self.hi is None else max(self.hi, self.samples)
        return True


class PipeWireAudio(AlsaAudio):
    """``audio.backend: pipewire``; see the module docstring."""

    #: a server that went away makes every read and write fail at once with -EPIPE
    MAX_XRUNS_IN_A_ROW = 20

    def __init__(self, cfg: Config, server: sound_server.SoundServer | None = None) -> None:
        super().__init__(cfg)
        self.server = server
        self.graph: dict[str, Any] = {}
        self.latency = StreamLatency(self.pri)
        self._lost_pulses = 0

    # -- opening -------------------------------------------------------------------------

    def _wait_for_server(self) -> sound_server.SoundServer:
        deadline = time.monotonic() + CONNECT_WAIT_S
        while True:
            found = sound_server.detect()
            if found.kind == "pipewire" or time.monotonic() > deadline:
                break
            if found.kind == "pulseaudio":
                raise AudioDeviceError(sound_server.pulseaudio_refusal(found))
            time.sleep(0.25)
        if found.kind == "pulseaudio":
            raise AudioDeviceError(sound_server.pulseaudio_refusal(found))
        if found.kind != "pipewire":
            raise AudioDeviceError(
                "audio.backend pipewire: no PipeWire server answers at "
                f"{sound_server.pipewire_socket(os.environ) or '$XDG_RUNTIME_DIR/pipewire-0'} "
                "(is XDG_RUNTIME_DIR the session's, e.g. /run/user/1000, and is pipewire "
                "running there: `systemctl --user status pipewire`?); on a board without a "
                "sound server use audio.backend: alsa")
        return found

    def _inspect_graph(self) -> None:
        """Before the streams open: the graph's rate (refused unless it is ours: the PRI
        is counted in our samples, and a resampler between the streams would blur the
        pulse schedule) and the nodes the streams will go to (logged, in stats). Not
        probed again once the streams run: a client joining the graph was seen to shift
        the latency between the streams by a quantum."""
        a = self.cfg.audio
        deadline = time.monotonic() + CONNECT_WAIT_S
        while True:
            dump = sound_server.pw_dump()
            if dump is None:
                log.warning("pw-dump (pipewire-bin) gave no graph: the rate and the targets "
                            "are not checked")
                return
            facts = sound_server.graph_facts(dump, os.getpid())
            facts.update(sound_server.target_facts(dump, a.playback_device, a.capture_device))
            missing = facts["playback"].get("missing") or facts["capture"].get("missing")
            if not missing or time.monotonic() > deadline:
                break
            time.sleep(0.25)     # a (re)starting server's nodes appear after its socket
        self.graph = facts
        want = int(a.sample_rate)
        forced = facts.get("force_rate")
        running = [f.get("target_rate") for f in (facts["playback"], facts["capture"])
                   if f.get("target_rate")]
        rate = forced or (running[0] if running else facts.get("clock_rate"))
        allowed = str(facts.get("allowed_rates") or "")
        ok = want == rate or (not forced and not running
                              and str(want) in re.findall(r"\d+", allowed))
        if rate and not ok:
            pri = round(self.cfg.waveform.pri_samples * rate / want)
            raise AudioDeviceError(
                f"audio.sample_rate {want}: the PipeWire graph runs at {rate} Hz "
                f"(allowed rates {allowed or '-'}), and a stream at another rate would be "
                f"resampled; set audio.sample_rate: {rate} and waveform.pri_samples: {pri} "
                "(the same pulse rate), or add the rate to the server's "
                "default.clock.allowed-rates")
        for kind in ("playback", "capture"):
            f = facts[kind]
            key = f"audio.{kind}_device"
            if f.get("missing"):
                raise AudioDeviceError(
                    f"{key} {getattr(a, kind + '_device')!r}: no such PipeWire node (or no "
                    "default one); `wpctl status` lists them, `wpctl inspect ID` shows the "
                    "node.name")
            log.info("PipeWire %s -> %s (%s, %s Hz)", kind, f.get("target"),
                     f.get("target_class"), f.get("target_rate") or "idle")
            if f.get("echo_cancel"):
                log.warning("the %s stream goes to an echo-cancel filter (%s): it removes the "
                            "echoes the sonar needs; name the device node in %s", kind,
                            f.get("target"), key)

    def start(self) -> None:
        self.server = self._wait_for_server()
        a = self.cfg.audio
        self._play_name = pcm_name(a.playback_device, "playback_device")
        self._cap_name = pcm_name(a.capture_device, "capture_device")
        self._inspect_graph()
        os.environ["PIPEWIRE_PROPS"] = stream_props_text()
        alsa = _alsaaudio()
        self._play = self._open(alsa, "playback", self._play_name)
        try:
            self._cap = self._open(alsa, "capture", self._cap_name)
        except AudioDeviceError:
            self._play.close()
            self._play = None
            raise
        self._start_threads()

    def _seen(self, b: PulseBlock) -> None:
        if self.latency.push(b.samples, b.start_sample, b.discontinuity) \
                or self.latency.samples is None:
            self._lost_pulses = 0
            return
        self._lost_pulses += 1
        if self._lost_pulses * self.pri > SILENT_S * self.cfg.audio.sample_rate \
                and self.failure is None:
            # the pulses came back, then stopped: a node suspended or taken away under
            # the streams (the graph then feeds silence, not a stall). Ending the path
            # makes the daemon reopen the streams, which resumes the nodes; a speaker
            # muted for good costs a reopen every few seconds, nothing else
            self.failure = f"no direct-coupling pulse through PipeWire for {SILENT_S:g} s"
            log.warning("%s: the streams' nodes are suspended or gone; reopening",
                        self.failure)
            self._ring.close()
            self._stop.set()

    def read_pulse(self, timeout: float) -> PulseBlock | None:
        b = super().read_pulse(timeout) if not self._stop.is_set() else None
        if b is not None:
            self._seen(b)
        return b

    def read_pulses(self, n: int, timeout: float) -> list[PulseBlock]:
        if self._stop.is_set():
            time.sleep(max(0.0, min(timeout, 0.5)))   # a closed path: wait like a stall
            return []
        got = super().read_pulses(n, timeout)
        for b in got:
            self._seen(b)
        return got

    def stats(self) -> dict[str, Any]:
        """The ALSA counters, plus what was found in the graph (one nested object, so
        the daemon's per-session sums leave it as it is)."""
        st: dict[str, Any] = dict(super().stats())
        fs = float(self.cfg.audio.sample_rate)
        g, lat = self.graph, self.latency

        def ms(n: int | None) -> float | None:
            return None if n is None else round(1e3 * n / fs, 2)

        st["sound_server"] = {
            "server": self.server.kind if self.server else None,
            "path": "pipewire-alsa",
            "backend": self.choice.get("backend", "pipewire"),
            "version": g.get("version"),
            "graph_rate": sound_server.graph_rate(g) if g else None,
            "quantum": g.get("force_quantum") or g.get("quantum"),
            "playback_target": (g.get("playback") or {}).get("target"),
            "capture_target": (g.get("capture") or {}).get("target"),
            "resampled": bool(g) and sound_server.graph_rate(g) != self.cfg.audio.sample_rate,
            "echo_cancel": any(bool((g.get(k) or {}).get("echo_cancel"))
                               for k in ("playback", "capture")),
            "stream_latency_ms": ms(lat.samples),
            "stream_latency_first_ms": ms(lat.first),
            "stream_latency_range_ms": None if lat.lo is None or lat.hi is None
            else [ms(lat.lo), ms(lat.hi)],
            "stream_latency_jumps": lat.jumps,
        }
        return st
