"""How the coordinator starts Python children (``--local-nodes``' render nodes, the upload check) on
its own packages: ``server`` and ``node`` are generic top-level names, and ``python -m node`` puts
the working folder first on the import path, where a user's own ``node.py`` or ``node/`` would win.
So children run with ``-P`` (no working folder on the path, Python 3.11) and ``PYTHONPATH`` led by
the folder this coordinator's packages were imported from (a checkout, or site-packages)."""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping
from pathlib import Path

#: The folder holding the ``server``, ``node`` and ``tessera`` packages this process runs.
PACKAGE_ROOT = Path(__file__).resolve().parent.parent


def module_command(module: str, *args: str) -> list[str]:
    """``python -P -m MODULE ARGS`` with this interpreter."""
    return [sys.executable, "-P", "-m", module, *args]


def child_environment(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """``environ`` (default this process's) with :data:`PACKAGE_ROOT` first on ``PYTHONPATH``."""
    env = dict(os.environ if environ is None else environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(PACKAGE_ROOT), env.get("PYTHONPATH")]))
    return env
