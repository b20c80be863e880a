"""The console commands ``pip install`` gives (pyproject.toml [project.scripts]): installed beside the
test interpreter, each answers ``--help`` with the same options as ``python -m server`` / ``python -m node``,
its usage naming the command as it was invoked; the help is in a user's words (issue 38)."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from bench.processes import PYTHON, REPO

SCRIPTS = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
BIN = Path(sys.executable).parent


def test_pyproject_names_both_commands():
    assert SCRIPTS == {"tessera-server": "server.__main__:main", "tessera-node": "node.__main__:main"}


@pytest.mark.parametrize(("command", "module", "option"),
                         [("tessera-server", "server", "--local-nodes"), ("tessera-node", "node", "--render-once")])
def test_installed_command_answers_help_like_python_m(command, module, option):
    script = BIN / command
    assert script.is_file(), f"{script} missing: run pip install -e . in this environment"
    installed = subprocess.run([str(script), "--help"], capture_output=True, text=True, timeout=60, check=False)
    assert installed.returncode == 0, installed.stderr
    assert option in installed.stdout
    by_module = subprocess.run([PYTHON, "-m", module, "--help"], capture_output=True, text=True, timeout=60,
                               check=False, cwd=REPO)
    assert installed.stdout.startswith(f"usage: {command} [-h]")
    assert by_module.stdout.startswith(f"usage: python -m {module} [-h]")
    assert options(installed.stdout) == options(by_module.stdout)


def options(help_text: str) -> str:
    """The help's option lines, without the usage (which names the command and wraps by its length)."""
    return help_text[help_text.index("\noptions:"):]


@pytest.mark.parametrize("module", ["server", "node"])
def test_help_speaks_a_users_words_not_the_design_notes(module):
    shown = subprocess.run([PYTHON, "-m", module, "--help"], capture_output=True, text=True, timeout=60,
                           check=True, cwd=REPO).stdout
    jargon = re.findall(r"(?i)\bseed \d+|§|\bissue \d+|\bbench\.\w+", shown)
    assert not jargon, f"python -m {module} --help says {jargon}: seed and section references belong in the docs"
