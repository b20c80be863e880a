"""examples/ run as a user runs them (issue 33): the notebook executed by nbclient in a real kernel
and the script in a process of its own, both against a real coordinator with a local node. Nothing
of their output is kept in the repository."""

from __future__ import annotations

import subprocess

import httpx
import nbformat
import numpy as np
import pytest
from nbclient import NotebookClient
from PIL import Image

from tests.conftest import PYTHON, REPO, seconds

pytestmark = [pytest.mark.integration, pytest.mark.gl]

EXAMPLES = REPO / "examples"


@pytest.fixture
def coordinator(coordinator_factory, tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    return coordinator_factory("--local-nodes", "1", "--size", "320x180", "--data-dir", str(data))


def test_the_notebook_runs_against_a_real_coordinator(coordinator, tmp_path, monkeypatch):
    source = EXAMPLES / "tessera_from_python.ipynb"
    notebook = nbformat.read(source, as_version=4)
    assert all(not cell.get("outputs") for cell in notebook.cells if cell.cell_type == "code"), \
        "the example is kept without outputs"
    monkeypatch.setenv("TESSERA_URL", coordinator.url)
    client = NotebookClient(notebook, timeout=int(seconds(300)), kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    outputs = [output for cell in notebook.cells if cell.cell_type == "code" for output in cell.outputs]
    assert not [output for output in outputs if output.output_type == "error"]
    printed = "".join(output.get("text", "") for output in outputs if output.output_type == "stream")
    assert "(360, 640, 3) uint8" in printed and printed.count("step ") == 3
    widgets = [output for output in outputs if "application/vnd.jupyter.widget-view+json" in output.get("data", {})]
    assert len(widgets) == 1, "the live view was displayed"
    images = [output for output in outputs if "image/png" in output.get("data", {})]
    assert len(images) == 2
    sessions = httpx.get(f"{coordinator.url}/api/sessions", timeout=seconds(30)).json()
    assert [session["id"] for session in sessions] == ["default"], "the notebook closed its session"


def test_the_script_saves_a_picture_per_step(coordinator, tmp_path):
    result = subprocess.run([PYTHON, str(EXAMPLES / "orbit_and_save.py"), "--url", coordinator.url, "--steps", "2",
                             "--out", str(tmp_path / "shots")], capture_output=True, text=True, timeout=seconds(300))
    assert result.returncode == 0, result.stderr
    shots = sorted((tmp_path / "shots").glob("*.png"))
    assert [shot.name for shot in shots] == ["00.png", "01.png"]
    first, second = (np.asarray(Image.open(shot).convert("RGB")) for shot in shots)
    assert first.shape == (360, 640, 3) and np.abs(first.astype(int) - second).mean() > 1.0, "the view turned"
