"""The console commands ``pip install`` gives (pyproject.toml [project.scripts]): installed beside the
test interpreter, each answers ``--help`` with the same options as ``python -m server`` / ``python -m node``."""

from __future__ import annotations

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
    assert installed.stdout == by_module.stdout
