"""cli.py lists its subcommands explicitly: every module in bladesonar/commands is one, and
a command module that is missing or renamed stops the program with an ImportError
instead of its subcommand silently vanishing from ``bladesonar --help``."""

from __future__ import annotations

import os
import pkgutil
import shutil
import subprocess
import sys
from pathlib import Path

import bladesonar.commands
from bladesonar import cli


def _subcommands() -> set[str]:
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert sub.choices is not None
    return set(sub.choices)


def test_every_command_module_is_a_subcommand():
    modules = {m.name for m in pkgutil.iter_modules(bladesonar.commands.__path__)}
    assert {c.__name__.rsplit(".", 1)[1] for c in cli.COMMANDS} == modules
    assert _subcommands() == {m.replace("_", "-") for m in modules}


def test_a_missing_command_module_is_an_import_error(repo_root, tmp_path):
    """A copy of the package without commands/plot.py: ``--help`` fails and names it."""
    pkg = tmp_path / "bladesonar"
    shutil.copytree(Path(repo_root) / "daemon" / "bladesonar", pkg,
                    ignore=shutil.ignore_patterns("__pycache__"))
    (pkg / "commands" / "plot.py").unlink()
    env = dict(os.environ, PYTHONPATH=str(tmp_path))
    r = subprocess.run([sys.executable, "-m", "bladesonar", "--help"], capture_output=True,
                       text=True, timeout=60, cwd=tmp_path, env=env)
    assert r.returncode != 0, r.stdout
    assert "ImportError" in r.stderr and "plot" in r.stderr, r.stderr
