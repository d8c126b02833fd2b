"""PipeWire backend: the ALSA backend's two threads on PipeWire's ALSA plugin PCM.

Why the plugin and not pw-cat or a native binding: it keeps the ALSA path's tested code
(the global sample counter, whole-period reads, xrun handling) and needs no new Python
package, and measured on the headless graph it delivers sample-exact periods at the
graph's clock (docs/audio.md). Both streams belong to one graph, so they share its clock
and sample grid; the backend makes sure nothing is resampled (our rate must be the
graph's) and asks, through the stream properties, that the server neither moves, pauses
nor suspends our streams. Echo cancellation, AGC and noise suppression in PipeWire are
filter nodes (module-echo-cancel), not stream properties: a stream linked to the device
node directly never passes through them, and the backend says when one of ours is linked
to such a filter.
"""

from __future__ import annotations

import logging
import os
import re
import statistics
import threading
import time
from collections import deque
from typing import Any

from ..errors import AudioDeviceError
from . import sound_server
from .alsa_audio import AlsaAudio, _alsaaudio

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
#: How many capture periods the stream-lead median spans.
LEAD_WINDOW = 16

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


class PipeWireAudio(AlsaAudio):
    """``audio.backend: pipewire``; see the module docstring."""

    def __init__(self, cfg: Any, server: sound_server.SoundServer | None = None) -> None:
        super().__init__(cfg)
        self.server = server
        self.graph: dict[str, Any] = {}
        self.resampled = False
        self._leads: deque[int] = deque(maxlen=LEAD_WINDOW)
        self._probe: threading.Thread | None = None

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

    def _check_rate_before(self) -> None:
        """Refuse a rate the graph would resample: the PRI is counted in our samples, and
        a resampler between the streams would blur the pulse schedule."""
        dump = sound_server.pw_dump()
        if dump is None:
            return
        facts = sound_server.graph_facts(dump, os.getpid())
        want = int(self.cfg.audio.sample_rate)
        forced = facts.get("force_rate")
        rate = forced or facts.get("clock_rate")
        allowed = str(facts.get("allowed_rates") or "")
        ok = want == rate or (not forced and str(want) in re.findall(r"\d+", allowed))
        if rate and not ok:
            pri = round(self.cfg.waveform.pri_samples * rate / want)
            raise AudioDeviceError(
                f"audio.sample_rate {want}: the PipeWire graph runs at {rate} Hz "
                f"(allowed rates {allowed or '-'}), and a stream at another rate would be "
                f"resampled; set audio.sample_rate: {rate} and waveform.pri_samples: {pri} "
                "(the same pulse rate), or add the rate to the server's "
                "default.clock.allowed-rates")

    def start(self) -> None:
        self.server = self._wait_for_server()
        a = self.cfg.audio
        self._play_name = pcm_name(a.playback_device, "playback_device")
        self._cap_name = pcm_name(a.capture_device, "capture_device")
        self._check_rate_before()
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
        self._probe = threading.Thread(target=self._inspect_graph, name="bladesonar-pw-probe",
                                       daemon=True)
        self._probe.start()

    def _inspect_graph(self) -> None:
        """Once audio flows: where our streams are linked, at what rate (logged, in stats)."""
        deadline = time.monotonic() + 10.0
        while self.periods_read < 1 and not self._stop.is_set():
            if time.monotonic() > deadline:
                return
            time.sleep(0.05)
        for _ in range(20):          # the session manager links the streams shortly after
            if self._stop.wait(0.1):
                return
            dump = sound_server.pw_dump()
            if dump is None:
                return
            facts = sound_server.graph_facts(dump, os.getpid())
            if all((facts.get(k) or {}).get("target") for k in ("playback", "capture")):
                break
        self.graph = facts
        want = int(self.cfg.audio.sample_rate)
        rate = sound_server.graph_rate(facts)
        self.resampled = bool(rate and rate != want)
        for kind in ("playback", "capture"):
            f = facts.get(kind) or {}
            log.info("PipeWire %s stream %s -> %s (%s, %s Hz)", kind, f.get("node"),
                     f.get("target"), f.get("target_class"), f.get("target_rate"))
            if f.get("echo_cancel"):
                log.warning("the %s stream is linked to an echo-cancel filter (%s): it removes "
                            "the echoes the sonar needs; name the device node in "
                            "audio.%s_device", kind, f.get("target"), kind)
        if self.resampled:
            log.error("the PipeWire graph runs at %s Hz, the streams at %s Hz: the server "
                      "resamples them; set audio.sample_rate: %s", rate, want, rate)

    def _on_period(self, capture_end: int) -> None:
        """Played minus captured samples when a capture period arrives: the latency
        between the two streams plus what the playback buffer holds, to a period."""
        self._leads.append(self.samples_written - capture_end)

    def stats(self) -> dict[str, Any]:
        st: dict[str, Any] = dict(super().stats())
        fs = float(self.cfg.audio.sample_rate)
        g = self.graph
        st.update({
            "server": self.server.kind if self.server else None,
            "backend": "pipewire (ALSA plugin)",
            "server_version": g.get("version"),
            "graph_rate": sound_server.graph_rate(g) if g else None,
            "quantum": g.get("force_quantum") or g.get("quantum"),
            "playback_target": (g.get("playback") or {}).get("target"),
            "capture_target": (g.get("capture") or {}).get("target"),
            "resampled": self.resampled,
            "echo_cancel": any((g.get(k) or {}).get("echo_cancel")
                               for k in ("playback", "capture")),
            "stream_lead_ms": (round(1e3 * statistics.median(self._leads) / fs, 1)
                               if self._leads else None),
        })
        return st
