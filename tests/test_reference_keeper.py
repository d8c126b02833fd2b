"""service/reference_keeper.py's file watch on a real file, with a clock that is a number.

The daemon tests drive the keeper through a real broker and sound path; here its poll
contract is checked step by step. The reference loader, the analyzer factory and the
publisher are stand-ins (they record what they are asked), because what is under test
is when the keeper reads the file and what it says, not the analysis.
"""

from __future__ import annotations

import types
from pathlib import Path
from typing import Any

from bladesonar import config
from bladesonar.errors import ReferenceFileError, ReferenceMissingError
from bladesonar.reference_build import SPEED_ADVICE
from bladesonar.service.airflow_watch import AirflowWatch
from bladesonar.service.learner import JobResult
from bladesonar.service.reference_keeper import (
    OTHER_SPEED_S,
    REFERENCE_POLL_S,
    ReferenceKeeper,
)


class Events:
    """The publisher's event calls, as the broker would carry them (kind, details)."""

    def __init__(self) -> None:
        self.sent: list[tuple[str, dict[str, Any]]] = []

    def publish_event(self, kind: str, **details: Any) -> None:
        self.sent.append((kind, details))


class Host:
    def __init__(self, cfg: config.Config) -> None:
        self.cfg = cfg
        self.publisher: Any = Events()
        self.airflow = AirflowWatch(cfg)
        self.statuses = 0

    def _status(self) -> tuple[str, str | None]:
        return "ok", None

    def _publish_status(self) -> None:
        self.statuses += 1

    def _publish_unknown(self) -> None:
        pass


class NullNotifier:
    def status(self, text: str) -> None:
        pass


def load(cfg: config.Config) -> Any:
    """The file's text is its id; "bad" is an invalid reference."""
    p = Path(cfg.reference_path)
    if not p.exists():
        raise ReferenceMissingError(f"no reference at {p}; make one with bladesonar reference")
    text = p.read_text()
    if text == "bad":
        raise ReferenceFileError(f"{p} is not a reference")
    return types.SimpleNamespace(meta={"id": text, "direction": "cw", "quality": 0.0})


def test_missing_then_written_then_replaced(tmp_path: Path) -> None:
    """Missing: one event, no learning advice to make one by hand (auto_learn), and the
    same absent file is not reported again. Written: loaded at the first poll at least
    REFERENCE_POLL_S after the last try. Replaced under the analysis: dropped and read
    again at the next check. Made invalid: one reference_invalid event."""
    cfg = config.from_mapping({"daemon": {"state_dir": str(tmp_path / "state")}})
    assert Path(cfg.reference_path).is_relative_to(tmp_path)   # never the system's
    Path(cfg.reference_path).parent.mkdir(parents=True)
    host = Host(cfg)
    t = [100.0]
    built: list[Any] = []

    def factory(c: config.Config, ref: Any) -> Any:
        built.append(ref)
        return types.SimpleNamespace(reference_id=ref.meta["id"])

    k = ReferenceKeeper(host, reference_loader=load, analyzer_factory=factory,
                        notifier=NullNotifier(), clock=lambda: t[0])  # type: ignore[arg-type]
    assert k.poll(t[0], busy=False) is False
    assert [e for e, _ in host.publisher.sent] == ["reference_missing"]
    assert "make one" not in host.publisher.sent[0][1]["detail"]
    assert k.missing and k.learn_allowed()          # auto_learn is on by default
    t[0] += REFERENCE_POLL_S
    assert k.poll(t[0], busy=False) is False        # the same absent file: nothing new
    assert len(host.publisher.sent) == 1

    Path(cfg.reference_path).write_text("ref-A")
    t[0] += REFERENCE_POLL_S - 0.5
    assert k.poll(t[0], busy=False) is False        # not yet due
    t[0] += 0.5
    assert k.poll(t[0], busy=True) is False         # a job may be writing the file
    assert k.poll(t[0], busy=False) is True
    assert k.reference is not None and k.reference.meta["id"] == "ref-A"
    assert k.analyzer is not None and k.problem is None and not k.missing
    assert k.status_fields() == {"reference": "ref-A", "reference_direction": "cw",
                                 "reference_rate_hz": None, "fit": None}

    Path(cfg.reference_path).write_text("ref-BB")   # another size: another signature
    t[0] += REFERENCE_POLL_S
    assert k.poll(t[0], busy=False) is True         # dropped and read again at once
    assert [r.meta["id"] for r in built] == ["ref-A", "ref-BB"]
    t[0] += REFERENCE_POLL_S
    assert k.poll(t[0], busy=False) is False        # unchanged: kept
    assert len(built) == 2

    Path(cfg.reference_path).write_text("bad")
    t[0] += REFERENCE_POLL_S
    assert k.poll(t[0], busy=False) is False
    assert host.publisher.sent[-1][0] == "reference_invalid"
    assert k.reference is None and k.analyzer is None and not k.missing
    t[0] += REFERENCE_POLL_S
    k.poll(t[0], busy=False)
    assert [e for e, _ in host.publisher.sent] == ["reference_missing", "reference_invalid"]


def test_a_reference_the_daemon_learned_at_a_poor_speed_is_learned_again_at_another(
        tmp_path: Path) -> None:
    """A reference the daemon learned by itself whose warnings ask for another fan speed
    (reference_build.SPEED_ADVICE: its pulses show few of the blade angles) is learned
    again once the fan has turned steadily at a speed 3 % or more off for OTHER_SPEED_S
    of fit samples (one a second), or at once when the airflow's reference-free window
    measures such a speed from the blade period: not at 0.2 % off, not before the time
    is up, not once the speed is unsettled (the count starts again), and never for a
    reference a person made or asked for, one without the warning, or with
    reference.auto_learn off. The analyzer is a stand-in whose published speed the test
    sets (see the module)."""
    warned = [f"the reference turns 0.019994 blade periods per pulse ...; {SPEED_ADVICE}"]

    def keeper(meta: dict[str, Any], auto: bool, speed: list[float | None]
               ) -> tuple[ReferenceKeeper, list[float]]:
        """A keeper with a loaded stand-in reference of ``meta`` (0.2266 Hz) whose
        analyzer publishes ``speed[0]``; its clock, a number in a list."""
        cfg = config.from_mapping({"daemon": {"state_dir": str(tmp_path / "state")},
                                   "reference": {"auto_learn": auto}})
        Path(cfg.reference_path).parent.mkdir(parents=True, exist_ok=True)
        Path(cfg.reference_path).write_text("ref-A")

        def loader(c: config.Config) -> Any:
            return types.SimpleNamespace(meta={"id": "ref-A", "direction": "cw",
                                               "quality": 0.9, "rate_hz": 0.2266, **meta})

        def factory(c: config.Config, ref: Any) -> Any:
            return types.SimpleNamespace(reference_id="ref-A",
                                         fit_sample=lambda: (True, 0.9),
                                         steady_rate_hz=lambda: speed[0])

        t = [100.0]
        k = ReferenceKeeper(Host(cfg), reference_loader=loader, analyzer_factory=factory,
                            notifier=NullNotifier(), clock=lambda: t[0])  # type: ignore[arg-type]
        assert k.poll(t[0], busy=False) is True
        return k, t

    def run(meta: dict[str, Any], speeds: list[float | None], auto: bool = True,
            window: float | None = None) -> list[str | None]:
        speed: list[float | None] = [None]
        k, t = keeper(meta, auto, speed)
        if k.speed_watched:
            k.note_window_speed(window)
        due: list[str | None] = []
        for v in speeds:
            t[0] += 1.0
            speed[0] = v
            k.sample_fit(t[0])
            due.append(k.learn_due(t[0]))
        return due

    ours = {"warnings": warned, "learned_by": "auto"}
    n = int(OTHER_SPEED_S)
    assert run(ours, [0.227] * 30) == [None] * 30                 # 0.2 % off: the same speed
    got = run(ours, [0.236] * (n + 1))                            # 4 % faster
    assert got[:n] == [None] * n and got[n] == "speed", got
    got = run(ours, [0.219] * (n - 1) + [None] + [0.219] * (n + 1))   # 3.4 % slower
    assert got.index("speed") == 2 * n, got                       # counted again from the gap
    assert run({**ours, "learned_by": "relearn"}, [0.236] * (n + 1))[-1] == "speed"
    # the blade period's window: another speed at once, whatever the answers say
    assert run(ours, [None] * 3, window=-0.236) == ["speed"] * 3
    assert run(ours, [None] * 3, window=0.227) == [None] * 3
    # one relearn at another speed per reference.retry_max_s, whatever the window says
    # after it (a misread speed must not make a learning loop)
    k, t = keeper(ours, True, [None])
    k.sample_fit(t[0])
    k.note_window_speed(0.236)
    assert k.learn_due(t[0]) == "speed"
    assert k.learned(JobResult("learn", value={"id": "ref-B", "warnings": []}), "speed")
    t[0] += REFERENCE_POLL_S
    assert k.poll(t[0], busy=False) is True         # (the stand-in reads ref-A's warning)
    k.note_window_speed(0.25)
    for dt in (60.0, k.host.cfg.reference.retry_max_s - 60.0 - REFERENCE_POLL_S - 1.0):
        t[0] += dt
        k.sample_fit(t[0])
        assert k.learn_due(t[0]) is None
    t[0] += 1.0
    k.sample_fit(t[0])
    assert k.learn_due(t[0]) == "speed"
    for meta, auto in (({"warnings": warned, "learned_by": "command"}, True),
                       ({"warnings": warned}, True),              # made by a person
                       ({"warnings": [], "learned_by": "auto"}, True),
                       (ours, False)):
        assert set(run(meta, [0.236] * (3 * n), auto=auto, window=0.236)) == {None}, \
            (meta, auto)


def test_a_learned_references_advice_is_logged_as_a_warning(
        tmp_path: Path, caplog: Any) -> None:
    """A headless user reads the journal (``journalctl -p warning``): each warning of a
    reference the daemon learned (another place, another speed) is logged at WARNING,
    besides the event's ``warnings``; a reference with none logs none."""
    cfg = config.from_mapping({"daemon": {"state_dir": str(tmp_path / "state")}})
    host = Host(cfg)

    def factory(c: config.Config, ref: Any) -> Any:
        return types.SimpleNamespace()

    k = ReferenceKeeper(host, reference_loader=load, analyzer_factory=factory,
                        notifier=NullNotifier(), clock=lambda: 0.0)  # type: ignore[arg-type]
    advice = "from here only 11 % of the fan's echoes match ...; a place nearer the fan"
    with caplog.at_level("WARNING", logger="bladesonar"):
        k.learned(JobResult("learn", value={"id": "ref-B", "warnings": [advice]}), "auto")
        k.learned(JobResult("learn", value={"id": "ref-C", "warnings": []}), "auto")
    got = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert got == [f"reference ref-B: {advice}"], got
    kind, details = host.publisher.sent[0]
    assert kind == "reference_learned" and details["warnings"] == [advice]
