"""Runs the viewer's JavaScript unit tests (tests/js/, `node --test`) as part of the pytest suite.

Without Node.js the test is skipped, except in CI (CI=true), where a missing node is a failure.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.conftest import seconds

JS_TESTS = Path(__file__).parent / "js"


def test_node_unit_tests_pass():
    node = shutil.which("node")
    if node is None:
        message = "Node.js (node >= 20) is needed to run the viewer's tests in tests/js/"
        if os.environ.get("CI") == "true":
            pytest.fail(message)
        pytest.skip(message)
    result = subprocess.run(
        [node, "--test", "tests/js/"], cwd=JS_TESTS.parents[1], capture_output=True, text=True,
        timeout=seconds(120), check=False,
    )
    assert result.returncode == 0, f"node --test tests/js/ failed:\n{result.stdout}\n{result.stderr}"
    assert "# fail 0" in result.stdout
