"""Faults around the daemon and the writers, on the real processes (sim backend, no broker):
a reference corrupted and restored under a running daemon, a SIGHUP during start-up,
temporary files left by a kill -9, a kill -9 in the middle of ``reference`` and of
``simulate`` writing, and a full disk under ``simulate``."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from bladesonar import config
from bladesonar.io.reference import load_reference, read_reference, save_reference
from bladesonar.io.scene_file import load_scene
from bladesonar.io.wav import WavWriter, read_wav
from bladesonar.reference_build import build_reference
from bladesonar.sim.render import simulate
from bladesonar.sim.schedule import Schedule
from loopback import ROOT, SCENE, bladesonar_cmd

pytestmark = [pytest.mark.slow, pytest.mark.realtime]


@pytest.fixture(scope="module")
def reference_file(tmp_path_factory) -> Path:
    cfg = config.Config()
    x, _ = simulate(load_scene(SCENE), cfg, 8.0, schedule=Schedule.constant(0.45, "ccw"),
                    snr_db=20.0, seed=5)
    return save_reference(build_reference(x, cfg, "ccw"),
                          tmp_path_factory.mktemp("ref") / "reference.npz")


def _config(tmp_path: Path, **sim) -> Path:
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(json.dumps({
        "audio": {"backend": "sim"}, "daemon": {"state_dir": str(tmp_path / "state"),
                                                "window_s": 2},
        "mqtt": {"publish_interval_s": 0.5},
        "sim": {"scene": str(SCENE), "schedule": "ccw:0.45:120", "realtime": True, **sim}}))
    (tmp_path / "state").mkdir(exist_ok=True)
    return cfg


def _env() -> dict:
    env = dict(os.environ)
    env.pop("NOTIFY_SOCKET", None)
    return env


class Daemon:
    """``bladesonar run`` with its stdout (JSON lines) read in a thread."""

    def __init__(self, cfg: Path, log: Path, seconds: float | None = None) -> None:
        args = ["run", "--config", str(cfg)] + (["--seconds", str(seconds)] if seconds else [])
        self.proc = subprocess.Popen(bladesonar_cmd(*args), stdout=subprocess.PIPE,
                                     stderr=open(log, "w"), text=True, cwd=ROOT, env=_env())
        self.log = log
        self.msgs: list[dict] = []
        self._t = threading.Thread(target=self._read, daemon=True)
        self._t.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None   # stdout=PIPE
        for ln in self.proc.stdout:
            if ln.startswith("{"):
                self.msgs.append(json.loads(ln))

    def states(self) -> list[dict]:
        return [m["payload"] for m in list(self.msgs) if m["topic"].endswith("/state")]

    def wait_state(self, pred, timeout: float, after: int = 0) -> dict:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for s in self.states()[after:]:
                if pred(s):
                    return s
            assert self.proc.poll() is None, f"daemon exited: {self.log.read_text()[-2000:]}"
            time.sleep(0.1)
        raise AssertionError(f"not seen in {timeout} s; states "
                             f"{[s.get('status') for s in self.states()]}; log "
                             f"{self.log.read_text()[-2000:]}")

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        rc = self.proc.wait(timeout=30)
        self._t.join(timeout=5)
        return rc


def test_reference_corrupted_and_restored_while_running(tmp_path, reference_file):
    """No SIGHUP: the file is stat'ed, so the daemon notices the damage within a few
    seconds, publishes reference_invalid with the reason, keeps running, and comes back
    when a good reference is stored again."""
    cfg = _config(tmp_path)
    ref = tmp_path / "state" / "reference.npz"
    good = reference_file.read_bytes()
    ref.write_bytes(good)
    d = Daemon(cfg, tmp_path / "daemon.log")
    try:
        d.wait_state(lambda s: s["status"] == "ok", 60)
        n = len(d.states())
        bad = bytearray(good)
        bad[len(bad) // 2] ^= 0x10
        tmp = ref.with_name("swap.tmp")
        tmp.write_bytes(bytes(bad))
        os.replace(tmp, ref)
        s = d.wait_state(lambda s: s["status"] == "reference_invalid", 15, after=n)
        assert "reference.npz" in s["detail"] and s["rate_hz"] is None
        n = len(d.states())
        tmp.write_bytes(good)
        os.replace(tmp, ref)
        d.wait_state(lambda s: s["status"] == "ok", 60, after=n)
    finally:
        rc = d.stop()
    log = (tmp_path / "daemon.log").read_text()
    assert rc == 0 and "Traceback" not in log
    kinds = [m["payload"]["kind"] for m in d.msgs if m["topic"].endswith("/event")]
    assert kinds.count("reference_invalid") == 1


def test_sighup_during_start_up_is_a_reload_not_a_death(tmp_path):
    cfg = _config(tmp_path)
    p = subprocess.Popen(bladesonar_cmd("run", "--config", str(cfg), "--seconds", "3"),
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                         cwd=ROOT, env=_env())
    # as soon as the process catches SIGHUP (SigCgt bit 0 in /proc), i.e. while it still
    # imports numpy and reads the config, long before the service exists
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            status = Path(f"/proc/{p.pid}/status").read_text()
        except OSError:
            break
        cgt = int(next(ln.split()[1] for ln in status.splitlines()
                       if ln.startswith("SigCgt:")), 16)
        if cgt & 1:
            break
        time.sleep(0.002)
    p.send_signal(signal.SIGHUP)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 0, err
    assert "configuration reloaded" in err


def test_stale_temporary_files_are_removed_at_start(tmp_path):
    cfg = _config(tmp_path)
    state = tmp_path / "state"
    stale = state / ".reference.npz.k9x1.tmp"
    fresh = state / ".reference.npz.w2a7.tmp"
    other = state / ".other.npz.k9x1.tmp"
    for f in (stale, fresh, other):
        f.write_bytes(b"half a reference")
    old = time.time() - 3600
    os.utime(stale, (old, old))
    os.utime(other, (old, old))
    r = subprocess.run(bladesonar_cmd("run", "--config", str(cfg), "--seconds", "0.5"),
                       capture_output=True, text=True, cwd=ROOT, env=_env(), timeout=60)
    assert r.returncode == 0, r.stderr
    # only the stale temp of this reference goes: a young one may be a write in progress
    assert not stale.exists() and fresh.exists() and other.exists()


#: The CLI as ``python -m bladesonar`` runs it, with an audit hook that stops the process
#: (SIGSTOP) at one point of an atomic write of the file named ``NAME``: ``created``, its
#: temporary file just created and still empty (the first ``open`` audit event on a file
#: descriptor, os.fdopen, after the ``tempfile.mkstemp`` event of that name, which comes
#: before the file exists), or ``complete``, the temporary file written and fsynced and
#: about to be renamed over ``NAME`` (the ``os.rename`` event, which ``os.replace``
#: raises). A breakpoint, not a mock: the code runs unchanged, and the test kills the
#: stopped process with SIGKILL exactly there.
_PAUSE_AT = r"""
import os, runpy, signal, sys
point, name = sys.argv[1], sys.argv[2]
armed = False

def hook(ev, args):
    global armed
    if ev == "tempfile.mkstemp":
        armed = os.path.basename(args[0]).startswith("." + name + ".")
    elif ev == "open" and armed and isinstance(args[0], int):
        armed = False
        if point == "created":
            os.kill(os.getpid(), signal.SIGSTOP)
    elif ev == "os.rename" and point == "complete" \
            and os.path.basename(os.fsdecode(args[1])) == name:
        os.kill(os.getpid(), signal.SIGSTOP)

sys.addaudithook(hook)
sys.argv = ["bladesonar", *sys.argv[3:]]
runpy.run_module("bladesonar", run_name="__main__", alter_sys=True)
"""


def _stop_at(point: str, name: str, *args: str) -> subprocess.Popen:
    """``bladesonar ARGS``, stopped at ``point`` of the atomic write of ``name``."""
    p = subprocess.Popen([sys.executable, "-c", _PAUSE_AT, point, name, *args],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                         cwd=ROOT, env=_env())
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if p.poll() is not None:
            raise AssertionError(f"exit {p.returncode} before {point} of {name}: "
                                 f"{p.communicate()[1][-2000:]}")
        stat = Path(f"/proc/{p.pid}/stat").read_text()
        if stat[stat.rindex(")") + 2] == "T":
            return p
        time.sleep(0.01)
    p.kill()
    raise AssertionError(f"not stopped at {point} of {name} within 60 s")


def _kill_9(p: subprocess.Popen) -> None:
    p.send_signal(signal.SIGKILL)
    p.communicate(timeout=30)
    assert p.returncode == -signal.SIGKILL


def _temps(folder: Path, name: str) -> list[Path]:
    """The hidden temporary files of atomic writes of ``name`` in ``folder``."""
    return sorted(q for q in folder.iterdir()
                  if q.name.startswith(f".{name}.") and q.name.endswith(".tmp"))


def _age(paths, seconds: float) -> None:
    """Set the mtime back, as if the kill had been ``seconds`` ago."""
    old = time.time() - seconds
    for q in paths:
        os.utime(q, (old, old))


def test_kill_9_during_a_reference_write_never_leaves_a_partial_reference(tmp_path,
                                                                          reference_file):
    """``bladesonar reference`` killed with SIGKILL at both edges of its write: just after
    its temporary file exists (no reference yet: none appears), and with the new reference
    complete in the temporary file, just before the rename (a previous reference in
    place: it stays, byte for byte, and loads with its checksum). Nothing partial is ever
    at the destination's name. A temporary file left behind goes when ``run`` starts once
    older than 60 s (mtime set back; a younger one stays), and ``run`` loads the previous
    reference; the next ``reference`` to that path clears the rest and writes in full."""
    cfg_path = _config(tmp_path)
    state = tmp_path / "state"
    dest = state / "reference.npz"
    x, _ = simulate(load_scene(SCENE), config.Config(), 8.0,
                    schedule=Schedule.constant(0.4, "ccw"), snr_db=20.0, seed=6)
    wav = tmp_path / "rec.wav"
    with WavWriter(wav, 44100) as w:
        w.write(x)
    args = ("reference", "--config", str(cfg_path), "--direction", "ccw", "--out",
            str(dest), str(wav))

    p = _stop_at("created", dest.name, *args)
    first = _temps(state, dest.name)
    assert len(first) == 1 and first[0].stat().st_size == 0 and not dest.exists()
    _kill_9(p)
    assert not dest.exists() and _temps(state, dest.name) == first

    previous = reference_file.read_bytes()
    dest.write_bytes(previous)
    p = _stop_at("complete", dest.name, *args)
    (second,) = set(_temps(state, dest.name)) - set(first)
    new = load_reference(second)          # the new reference, whole, not yet in place
    assert new.meta["rate_hz"] == pytest.approx(0.4, rel=0.01)
    _kill_9(p)
    assert dest.read_bytes() == previous
    ref, digest = read_reference(dest)    # loads: structure, values and checksum
    assert digest == hashlib.sha256(previous).hexdigest()
    assert ref.meta["rate_hz"] == pytest.approx(0.45, rel=0.01)
    assert sorted(state.iterdir()) == sorted([dest, *first, second])

    # run: the temporary files older than 60 s go, a young one may be a write going on
    _age(first, 120)
    r = subprocess.run(bladesonar_cmd("run", "--config", str(cfg_path), "--seconds", "0.5"),
                       capture_output=True, text=True, cwd=ROOT, env=_env(), timeout=60)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert _temps(state, dest.name) == [second] and dest.read_bytes() == previous
    assert r.stderr.count("left by an interrupted write") == 1
    assert f"reference loaded: {digest[:12]}" in r.stderr
    # the next reference to that path clears what is stale, then writes in full
    _age([second], 120)
    r = subprocess.run(bladesonar_cmd(*args), capture_output=True, text=True, cwd=ROOT,
                       env=_env(), timeout=60)
    assert r.returncode == 0 and "left by an interrupted write" in r.stderr, r.stderr
    assert sorted(state.iterdir()) == [dest]
    assert load_reference(dest).meta["rate_hz"] == pytest.approx(0.4, rel=0.01)


def test_kill_9_during_simulate_never_leaves_a_partial_recording(tmp_path):
    """``simulate`` streams its WAV and truth sidecar into temporary files: killed with
    SIGKILL in the middle (samples flowing), the previous recording and sidecar stay as
    they were and still read; the next ``simulate`` to the same path removes the
    temporary files once older than 60 s and writes a whole new pair."""
    out = tmp_path / "out" / "x.wav"
    truth = out.with_name("x.truth.json")

    def sim(seconds: float) -> list[str]:
        return bladesonar_cmd("simulate", "--scene", str(SCENE), "--seconds", str(seconds),
                              "--rate", "0.45", "--no-paths", "--quiet", "--out", str(out))

    r = subprocess.run(sim(2), capture_output=True, text=True, cwd=ROOT, env=_env(),
                       timeout=60)
    assert r.returncode == 0, r.stderr
    prev_wav, prev_truth = out.read_bytes(), truth.read_bytes()

    p = subprocess.Popen(sim(3600), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True, cwd=ROOT, env=_env())
    deadline = time.monotonic() + 60
    # until the samples stream in: more than the header and a first buffer on disk
    while not any(q.stat().st_size > 1 << 16 for q in _temps(out.parent, out.name)):
        assert p.poll() is None, p.communicate()[1][-2000:]
        assert time.monotonic() < deadline, "no temporary WAV growing within 60 s"
        time.sleep(0.02)
    _kill_9(p)
    left = [*_temps(out.parent, out.name), *_temps(out.parent, truth.name)]
    assert len(left) == 2
    assert out.read_bytes() == prev_wav and truth.read_bytes() == prev_truth
    assert len(read_wav(out)[0]) == 2 * 44100
    assert json.loads(truth.read_text())["summary"]["complete"] is True

    _age(left, 120)
    r = subprocess.run(sim(1), capture_output=True, text=True, cwd=ROOT, env=_env(),
                       timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stderr.count("left by an interrupted write") == 2
    assert sorted(out.parent.iterdir()) == sorted([out, truth])
    assert len(read_wav(out)[0]) == 44100
    assert json.loads(truth.read_text())["summary"]["complete"] is True


def test_simulate_on_a_full_disk_keeps_nothing_and_says_so_in_one_line(tmp_path):
    """RLIMIT_FSIZE stands in for a full disk (the write fails with EFBIG, as ENOSPC
    would): exit 2, one line, neither the WAV nor its truth sidecar nor a temp file."""
    out = tmp_path / "out"
    out.mkdir()
    # the shell's ulimit -f (512-byte blocks), not preexec_fn (unsafe with threads); Python
    # ignores SIGXFSZ, so the write fails with EFBIG instead of killing the process
    r = subprocess.run(["/bin/sh", "-c", 'ulimit -f 400 && exec "$@"', "small-disk",
                        *bladesonar_cmd("simulate", "--scene", str(SCENE), "--seconds", "10",
                                        "--rate", "0.45", "--out", str(out / "x.wav"),
                                        "--quiet")],
                       capture_output=True, text=True, cwd=ROOT, env=_env(), timeout=120)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bladesonar simulate: error: --out")
    assert "nothing was kept" in lines[0]
    assert list(out.iterdir()) == []


@pytest.mark.broker
def test_broker_restarts_a_reload_storm_and_a_bad_reference_through_a_real_broker(
        tmp_path, reference_file):
    """The daemon against mosquitto: two broker restarts, 30 SIGHUPs in a burst (the
    config unchanged: tracking goes on), a reference corrupted then restored. It never
    exits, states keep coming after each fault, the status goes reference_invalid and back
    to ok, and the invalid-reference event arrives exactly once."""
    from mosquitto import Mosquitto, Subscriber, require_mosquitto

    require_mosquitto()
    with Mosquitto(tmp_path / "broker") as broker:
        cfg = tmp_path / "cfg.yaml"
        cfg.write_text(json.dumps({
            "device_id": "faults",
            "audio": {"backend": "sim"},
            "daemon": {"state_dir": str(tmp_path / "state"), "window_s": 2},
            "mqtt": {"host": "127.0.0.1", "port": broker.port, "keepalive_s": 5,
                     "publish_interval_s": 0.5},
            "sim": {"scene": str(SCENE), "schedule": "ccw:0.45:300", "realtime": True}}))
        (tmp_path / "state").mkdir()
        ref = tmp_path / "state" / "reference.npz"
        good = reference_file.read_bytes()
        ref.write_bytes(good)
        state_t, event_t = "bladesonar/faults/state", "bladesonar/faults/event"
        log = tmp_path / "daemon.log"
        sub = Subscriber(broker.port, ["bladesonar/faults/#"])
        proc = subprocess.Popen(bladesonar_cmd("run", "--config", str(cfg)),
                                stdout=subprocess.DEVNULL, stderr=open(log, "w"),
                                cwd=ROOT, env=_env())

        def states(ms):
            return [json.loads(m.payload) for m in ms if m.topic == state_t]

        def new_state(pred, timeout):
            n = len(states(sub.messages))
            return sub.wait_until(lambda ms: any(pred(s) for s in states(ms)[n:]), timeout)

        try:
            new_state(lambda s: s["status"] == "ok", 60)
            for _ in range(2):
                broker.stop()
                time.sleep(1.0)
                broker.start()
                sub.close()
                sub = Subscriber(broker.port, ["bladesonar/faults/#"])
                new_state(lambda s: s["status"] == "ok", 30)
            for _ in range(30):
                proc.send_signal(signal.SIGHUP)
                time.sleep(0.01)
            new_state(lambda s: s["status"] == "ok", 10)
            bad = bytearray(good)
            bad[len(bad) // 3] ^= 0x01
            (tmp_path / "state" / "swap").write_bytes(bytes(bad))
            os.replace(tmp_path / "state" / "swap", ref)
            new_state(lambda s: s["status"] == "reference_invalid"
                      and "reference.npz" in s.get("detail", ""), 15)
            (tmp_path / "state" / "swap").write_bytes(good)
            os.replace(tmp_path / "state" / "swap", ref)
            new_state(lambda s: s["status"] == "ok", 60)
            assert proc.poll() is None, log.read_text()[-2000:]
        finally:
            proc.send_signal(signal.SIGTERM)
            try:
                rc = proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                raise AssertionError(
                    f"no exit 30 s after SIGTERM: {log.read_text()[-3000:]}") from None
            kinds = [json.loads(m.payload)["kind"] for m in sub.messages
                     if m.topic == event_t]
            sub.close()
    text = log.read_text()
    assert rc == 0 and "Traceback" not in text, text[-2000:]
    assert kinds.count("reference_invalid") == 1, kinds
    assert text.count("tracking goes on") >= 1


@pytest.mark.broker
def test_a_frozen_broker_neither_stops_the_daemon_nor_its_shutdown(tmp_path, reference_file):
    """mosquitto stopped with SIGSTOP (accepts nothing, closes nothing): the daemon notices
    the keepalive timeout, keeps running, and still stops within seconds on SIGTERM."""
    from mosquitto import Mosquitto, Subscriber, require_mosquitto

    require_mosquitto()
    with Mosquitto(tmp_path / "broker") as broker:
        cfg = tmp_path / "cfg.yaml"
        cfg.write_text(json.dumps({
            "device_id": "frozen", "audio": {"backend": "sim"},
            "daemon": {"state_dir": str(tmp_path / "state"), "window_s": 2},
            "mqtt": {"host": "127.0.0.1", "port": broker.port, "keepalive_s": 5,
                     "publish_interval_s": 0.5},
            "sim": {"scene": str(SCENE), "schedule": "ccw:0.45:300", "realtime": True}}))
        (tmp_path / "state").mkdir()
        (tmp_path / "state" / "reference.npz").write_bytes(reference_file.read_bytes())
        log = tmp_path / "daemon.log"
        proc = subprocess.Popen(bladesonar_cmd("run", "--config", str(cfg)),
                                stdout=subprocess.DEVNULL, stderr=open(log, "w"),
                                cwd=ROOT, env=_env())
        try:
            with Subscriber(broker.port, ["bladesonar/frozen/state"]) as sub:
                sub.wait_until(lambda ms: any(json.loads(m.payload)["status"] == "ok"
                                              for m in ms), 60)
            broker.pause()
            deadline = time.monotonic() + 20
            while "lost the connection" not in log.read_text():
                assert time.monotonic() < deadline, log.read_text()[-2000:]
                assert proc.poll() is None, log.read_text()[-2000:]
                time.sleep(0.2)
            t0 = time.monotonic()
            proc.send_signal(signal.SIGTERM)
            rc = proc.wait(timeout=15)
            took = time.monotonic() - t0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            broker.resume()
    assert rc == 0 and took < 10, (rc, took, log.read_text()[-2000:])
    assert "Traceback" not in log.read_text()


def test_a_storm_of_sighups_never_deadlocks_the_daemon(tmp_path, reference_file):
    """Signal handlers that take a lock (threading.Event.set) deadlock when the signal
    lands while the main thread holds that lock (Event.clear, Event.wait): a burst of
    SIGHUPs once froze the daemon for good, SIGTERM included. SIGHUPs as fast as they go
    for 3 s, then SIGTERM: it must still publish and stop."""
    cfg = _config(tmp_path)
    (tmp_path / "state" / "reference.npz").write_bytes(reference_file.read_bytes())
    d = Daemon(cfg, tmp_path / "daemon.log")
    try:
        d.wait_state(lambda s: s["status"] == "ok", 60)
        t_end = time.monotonic() + 3.0
        while time.monotonic() < t_end:
            d.proc.send_signal(signal.SIGHUP)
        n = len(d.states())
        d.wait_state(lambda s: s["status"] == "ok", 20, after=n)
        d.proc.send_signal(signal.SIGTERM)
        rc = d.proc.wait(timeout=15)
    finally:
        if d.proc.poll() is None:
            d.proc.kill()
            d.proc.wait()
    assert rc == 0, (tmp_path / "daemon.log").read_text()[-2000:]
    assert "Traceback" not in (tmp_path / "daemon.log").read_text()
