"""setup_logging: which handler, which format, and no duplicated lines.

The journal itself cannot be checked here (no journald in the test environment, and
binding /run/systemd/journal/socket would touch the host): the journal tests check that
``systemd.journal.JournalHandler`` is the handler chosen, with the identifier set, not
that a record arrives in the journal.
"""

from __future__ import annotations

import logging
import os
import re
import sys

import pytest

from bladesonar.service import logs
from bladesonar.service.logs import setup_logging

try:
    from systemd.journal import JournalHandler
except ImportError:  # the analysis-only install
    JournalHandler = None

needs_journal_module = pytest.mark.skipif(JournalHandler is None,
                                          reason="systemd-python not installed")


@pytest.fixture(autouse=True)
def restore_root_logger():
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    for h in list(root.handlers):
        if h not in handlers:
            root.removeHandler(h)
            h.close()
    for h in handlers:
        if h not in root.handlers:
            root.addHandler(h)
    root.setLevel(level)


@pytest.fixture
def err(tmp_path):
    """A real file as stderr: it has a device and inode, as the journal stream does."""
    with open(tmp_path / "stderr.txt", "w+", encoding="utf-8") as f:
        yield f


def journal_env(stream) -> dict[str, str]:
    st = os.fstat(stream.fileno())
    return {"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}


def ours() -> list[logging.Handler]:
    return [h for h in logging.getLogger().handlers if getattr(h, logs._MARK, False)]


def test_stderr_format_and_level(err):
    setup_logging(env={}, stream=err)
    log = logging.getLogger("bladesonar.test")
    log.info("reference loaded: %s", "abc123")
    log.debug("not shown at INFO")
    err.seek(0)
    lines = err.read().splitlines()
    assert len(lines) == 1
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3} INFO bladesonar\.test: "
                        r"reference loaded: abc123", lines[0]), lines


def test_debug_flag(err):
    setup_logging(True, env={}, stream=err)
    assert logging.getLogger().level == logging.DEBUG
    logging.getLogger("bladesonar.test").debug("shown")
    err.seek(0)
    assert err.read().rstrip().endswith("DEBUG bladesonar.test: shown")


def test_calling_twice_keeps_one_handler_and_replaces_basicconfig(err, caplog):
    root = logging.getLogger()
    plain = logging.StreamHandler(sys.stderr)  # what the CLI's basicConfig installs
    root.addHandler(plain)
    setup_logging(env={}, stream=err)
    setup_logging(env={}, stream=err)
    assert len(ours()) == 1
    assert plain not in root.handlers
    assert caplog.handler in root.handlers  # other handlers are left alone
    logging.getLogger("bladesonar.test").warning("once")
    err.seek(0)
    assert err.read().count("once") == 1
    setup_logging(True, env={}, stream=err)  # a second call may change the level
    assert len(ours()) == 1 and root.level == logging.DEBUG


@needs_journal_module
def test_journal_handler_when_stderr_is_the_journal_stream(err):
    h = setup_logging(env=journal_env(err), stream=err)
    assert isinstance(h, JournalHandler)
    assert h._extra.get("SYSLOG_IDENTIFIER") == "bladesonar"
    assert "asctime" not in h.formatter._fmt  # the journal stamps records itself
    assert ours() == [h]


def test_journal_stream_of_another_file_means_stderr(err, tmp_path):
    other = tmp_path / "other"
    other.write_text("")
    st = os.stat(other)
    h = setup_logging(env={"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}, stream=err)
    assert type(h) is logging.StreamHandler
    assert h.formatter is not None and "%(asctime)s" in str(h.formatter._fmt)


@pytest.mark.parametrize("value", ["", "garbage", "1:2:3", "x:y"])
def test_malformed_journal_stream_means_stderr(err, value):
    h = setup_logging(env={"JOURNAL_STREAM": value}, stream=err)
    assert type(h) is logging.StreamHandler


def test_invocation_id_alone_is_not_the_journal(err):
    # StandardError=file:... or tty under systemd: INVOCATION_ID is set all the same
    h = setup_logging(env={"INVOCATION_ID": "0123456789abcdef0123456789abcdef"}, stream=err)
    assert type(h) is logging.StreamHandler


def test_override_stderr_under_the_journal(err):
    env = journal_env(err) | {"BLADESONAR_LOG": "stderr"}
    h = setup_logging(env=env, stream=err)
    assert type(h) is logging.StreamHandler
    assert h.formatter is not None
    assert "asctime" not in str(h.formatter._fmt)  # stderr is the journal: no second time stamp
    logging.getLogger("bladesonar.test").error("boom")
    err.seek(0)
    assert err.read().strip() == "ERROR bladesonar.test: boom"


@needs_journal_module
def test_override_journal(err):
    assert isinstance(setup_logging(env={"BLADESONAR_LOG": "Journal"}, stream=err),
                      JournalHandler)


def test_journal_without_systemd_python_falls_back_to_stderr(err, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "systemd.journal", None)  # import now fails
    h = setup_logging(env=journal_env(err), stream=err)
    assert type(h) is logging.StreamHandler
    err.seek(0)
    text = err.read()
    assert "WARNING" in text and "systemd-python" in text


def test_unknown_override_is_reported_and_ignored(err, capsys):
    h = setup_logging(env={"BLADESONAR_LOG": "syslog"}, stream=err)
    assert type(h) is logging.StreamHandler
    assert "BLADESONAR_LOG='syslog'" in capsys.readouterr().err
