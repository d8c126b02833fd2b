"""Which sound server owns the card (from its sockets), and what a PipeWire graph holds
(from ``pw-dump``): its rate and quantum, and where our two streams are linked.

Parsing the dump is pure (``graph_facts``); finding sockets and running ``pw-dump`` are
the thin edges. PipeWire's PulseAudio front-end (pipewire-pulse) also serves
``pulse/native``, so a live ``pipewire-0`` socket means PipeWire whatever else is there.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import socket
import stat
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

#: How long ``pw-dump`` may take before the graph is reported as unknown.
DUMP_TIMEOUT_S = 5.0


@dataclass(frozen=True)
class SoundServer:
    kind: str
    """``pipewire``, ``pulseaudio`` or ``none``."""
    socket: str | None = None
    """The socket that answered."""

    def describe(self) -> str:
        return self.kind if self.socket is None else f"{self.kind} ({self.socket})"


def _live_socket(path: Path) -> bool:
    """A unix socket someone accepts connections on (a stale file left by a crashed
    server is not)."""
    try:
        if not stat.S_ISSOCK(path.stat().st_mode):
            return False
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.settimeout(1.0)
            s.connect(str(path))
        return True
    except OSError:
        return False


def pipewire_socket(env: Mapping[str, str]) -> Path | None:
    """Where libpipewire would connect: ``PIPEWIRE_REMOTE`` (default ``pipewire-0``) in
    ``PIPEWIRE_RUNTIME_DIR`` or ``XDG_RUNTIME_DIR``."""
    name = env.get("PIPEWIRE_REMOTE") or "pipewire-0"
    if name.startswith("/"):
        return Path(name)
    base = env.get("PIPEWIRE_RUNTIME_DIR") or env.get("XDG_RUNTIME_DIR")
    return Path(base) / name if base else None


def pulse_socket(env: Mapping[str, str]) -> Path | None:
    server = env.get("PULSE_SERVER", "")
    if server.startswith("unix:"):
        return Path(server[len("unix:"):])
    base = env.get("PULSE_RUNTIME_PATH") or (
        str(Path(env["XDG_RUNTIME_DIR"]) / "pulse") if env.get("XDG_RUNTIME_DIR") else None)
    if base:
        return Path(base) / "native"
    return Path("/run/pulse/native")     # a system-wide daemon (rare)


def detect(env: Mapping[str, str] | None = None) -> SoundServer:
    """The sound server this process's environment reaches, if any."""
    env = os.environ if env is None else env
    pw = pipewire_socket(env)
    if pw is not None and _live_socket(pw):
        return SoundServer("pipewire", str(pw))
    pa = pulse_socket(env)
    if pa is not None and _live_socket(pa):
        return SoundServer("pulseaudio", str(pa))
    return SoundServer("none")


def pulseaudio_refusal(server: SoundServer) -> str:
    return (f"a PulseAudio server owns the sound card ({server.socket}): bladesonar runs "
            "through PipeWire (audio.backend: pipewire) or on a bare ALSA device, not through "
            "PulseAudio, whose buffering and resampling have not been measured to keep the "
            "pulse schedule. Install PipeWire with its PulseAudio front-end "
            "(Debian: apt install pipewire-pulse wireplumber; postmarketOS: it is the default "
            "since v23.06), or stop PulseAudio and use a hw:/plughw: device")


# -- the graph, from pw-dump (pure) -----------------------------------------------------


def _metadata(dump: list[dict[str, Any]], name: str = "settings") -> dict[str, Any]:
    for obj in dump:
        if obj.get("type", "").endswith("Metadata") and \
                (obj.get("props") or {}).get("metadata.name") == name:
            return {m.get("key"): m.get("value") for m in obj.get("metadata") or []
                    if m.get("subject", 0) == 0}
    return {}


def _default_name(value: Any) -> str | None:
    """``default.audio.sink`` and the like hold ``{"name": "..."}`` (as JSON text or
    already parsed)."""
    if isinstance(value, str):
        try:
            value = json.loads(value)
        except ValueError:
            return value or None
    return value.get("name") if isinstance(value, dict) else None


def _node_target(node: dict[str, Any] | None) -> dict[str, Any]:
    props = ((node or {}).get("info") or {}).get("props") or {}
    name = str(props.get("node.name") or "")
    return {
        "target": name or None,
        "target_class": props.get("media.class"),
        "target_rate": _format_rate(node) if node else None,
        "echo_cancel": "echo-cancel" in name or "echo_cancel" in name
                       or "echo-cancel" in str(props.get("factory.name") or ""),
    }


def target_facts(dump: list[dict[str, Any]], playback: str, capture: str) -> dict[str, Any]:
    """Where our streams will go, read before they open (a client joining a running
    graph may shift the streams' latency by a quantum, so the daemon does not probe the
    graph once its streams run): the named nodes, or the server's defaults for
    ``default``; each one's class, running rate and whether it is an echo-cancel filter."""
    defaults = _metadata(dump, "default")
    nodes = {((o.get("info") or {}).get("props") or {}).get("node.name"): o for o in dump
             if o.get("type", "").endswith(":Node")}
    out: dict[str, Any] = {}
    for kind, name, key in (("playback", playback, "default.audio.sink"),
                            ("capture", capture, "default.audio.source")):
        if name in ("default", "pipewire", ""):
            name = _default_name(defaults.get(key)) or ""
        node = nodes.get(name)
        out[kind] = _node_target(node) if node else {"target": name or None,
                                                      "missing": True}
    return out


def _format_rate(node: dict[str, Any]) -> int | None:
    for f in ((node.get("info") or {}).get("params") or {}).get("Format") or []:
        rate = f.get("rate") if isinstance(f, dict) else None
        if isinstance(rate, int) and rate > 0:
            return rate
    return None


def _int(v: Any) -> int | None:
    try:
        return int(v)
    except (TypeError, ValueError):
        return None


def graph_facts(dump: list[dict[str, Any]], pid: int) -> dict[str, Any]:
    """What the graph says about process ``pid``'s streams: the server version, the
    graph's clock settings, and for each of our streams (playback, capture) the node it is
    linked to, that node's running rate, and whether an echo-cancel filter sits there."""
    nodes = {o["id"]: o for o in dump if o.get("type", "").endswith(":Node")}
    links = [o["info"] for o in dump if o.get("type", "").endswith(":Link") and o.get("info")]
    version = next((o["info"].get("version") for o in dump
                    if o.get("type", "").endswith(":Core") and o.get("info")), None)
    s = _metadata(dump)
    out: dict[str, Any] = {
        "version": version,
        "clock_rate": _int(s.get("clock.rate")),
        "force_rate": _int(s.get("clock.force-rate")) or None,
        "allowed_rates": s.get("clock.allowed-rates"),
        "quantum": _int(s.get("clock.quantum")),
        "force_quantum": _int(s.get("clock.force-quantum")) or None,
    }
    clients = {o["id"]: ((o.get("info") or {}).get("props") or {}) for o in dump
               if o.get("type", "").endswith(":Client")}
    for nid, node in nodes.items():
        props = (node.get("info") or {}).get("props") or {}
        owner = props.get("application.process.id") or \
            clients.get(_int(props.get("client.id")) or -1, {}).get("application.process.id")
        if _int(owner) != pid:
            continue
        cls = props.get("media.class", "")
        kind = "playback" if cls.startswith("Stream/Output") else \
            "capture" if cls.startswith("Stream/Input") else None
        if kind is None:
            continue
        peers = {ln.get("input-node-id") if kind == "playback" else ln.get("output-node-id")
                 for ln in links
                 if (ln.get("output-node-id") if kind == "playback"
                     else ln.get("input-node-id")) == nid}
        peer = next((nodes[p] for p in sorted(x for x in peers if x in nodes)), None)
        out[kind] = {"node": props.get("node.name"),
                     "state": (node.get("info") or {}).get("state"),
                     "rate": _format_rate(node), **_node_target(peer)}
    return out


def graph_rate(facts: Mapping[str, Any]) -> int | None:
    """The rate the graph runs at: a forced rate, else what our peers run at, else the
    default clock rate."""
    if facts.get("force_rate"):
        return int(facts["force_rate"])
    for kind in ("playback", "capture"):
        r = (facts.get(kind) or {}).get("target_rate")
        if r:
            return int(r)
    return facts.get("clock_rate")


# -- the edge ----------------------------------------------------------------------------


def pw_dump(env: Mapping[str, str] | None = None,
            timeout: float = DUMP_TIMEOUT_S) -> list[dict[str, Any]] | None:
    """The graph as ``pw-dump`` prints it (pipewire-bin), or None if it cannot be had."""
    exe = shutil.which("pw-dump")
    if exe is None:
        log.debug("pw-dump is not installed: the graph is not inspected")
        return None
    try:
        r = subprocess.run([exe], capture_output=True, text=True, timeout=timeout,
                           env=None if env is None else dict(env), check=False)
        data = json.loads(r.stdout) if r.returncode == 0 else None
    except (OSError, subprocess.TimeoutExpired, ValueError) as exc:
        log.debug("pw-dump failed: %s", exc)
        return None
    return data if isinstance(data, list) else None
