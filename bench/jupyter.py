"""A real ``jupyter lab`` for ``bench.notebook`` and the notebook tests: started on a free port with a
profile of its own (config, runtime and IPython folders under the folder it serves), its kernel the
Python running this; notebooks written with nbformat; the page's cells run as a user runs them."""

from __future__ import annotations

import contextlib
import os
import secrets
import socket
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import nbformat

from bench.processes import PYTHON, REPO, LoggedProcess


@dataclass
class JupyterLab:
    """A running ``jupyter lab``: its process, base URL and token."""

    proc: LoggedProcess
    url: str
    token: str
    root: Path

    def open_url(self, notebook: str) -> str:
        return f"{self.url}lab/tree/{notebook}?token={self.token}"


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@contextlib.contextmanager
def jupyter_lab(root: Path, timeout: float, port: int | None = None) -> Iterator[JupyterLab]:
    """``jupyter lab`` serving ``root`` on 127.0.0.1 (``port``: default a free one), ready to take
    requests (``timeout`` s at most). Its kernels import this checkout's packages: they start in
    ``root``, where a relative ``PYTHONPATH`` (``PYTHONPATH=.``) would name another folder."""
    token, port = secrets.token_hex(16), port or free_port()
    profile = root / ".jupyter-profile"
    paths = [str(REPO), *(os.path.abspath(p) for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p)]
    env = {"JUPYTER_CONFIG_DIR": str(profile / "config"), "JUPYTER_RUNTIME_DIR": str(profile / "runtime"),
           "IPYTHONDIR": str(profile / "ipython"), "JUPYTER_PLATFORM_DIRS": "1", "JUPYTER_NO_CONFIG": "1",
           "PYTHONPATH": os.pathsep.join(paths)}
    command = [PYTHON, "-m", "jupyterlab", "--no-browser", f"--ServerApp.port={port}", "--ServerApp.ip=127.0.0.1",
               f"--IdentityProvider.token={token}", "--allow-root", f"--ServerApp.root_dir={root}",
               "--ServerApp.port_retries=0",
               "--LabApp.news_url=", "--LabApp.check_for_updates_class=jupyterlab.NeverCheckForUpdate",
               "--ServerApp.terminals_enabled=False"]
    proc = LoggedProcess(command, env=env, new_session=True, stop_timeout=timeout)
    lab = JupyterLab(proc, f"http://127.0.0.1:{port}/", token, root)
    try:
        wait_answering(proc, f"{lab.url}api/status?token={token}", timeout, "jupyter lab")
        yield lab
    finally:
        proc.stop()


def wait_answering(proc: LoggedProcess, url: str, timeout: float, what: str) -> None:
    """Wait until ``url`` answers 200; RuntimeError with ``proc``'s output when ``proc`` exits or
    ``timeout`` s pass first."""
    deadline = time.monotonic() + timeout
    while True:
        with contextlib.suppress(httpx.HTTPError):
            if httpx.get(url, timeout=5).status_code == 200:
                return
        if proc.process.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError(f"{what} did not start:\n" + "\n".join(proc.lines))
        time.sleep(0.1)


def write_notebook(path: Path, cells: list[str]) -> Path:
    """A notebook of code ``cells`` at ``path``."""
    notebook = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(source) for source in cells])
    notebook.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nbformat.write(notebook, path)
    return path


#: The notebook view's state (``el.tesseraView`` of its output element), or null before it renders.
VIEW_STATE_JS = """() => {
  const median = (values) => values && values.length ? [...values].sort((a, b) => a - b)[values.length >> 1] : null;
  const box = document.querySelector(".tessera-view");
  const state = box && box.parentElement.tesseraView;
  return state ? {framesDrawn: state.framesDrawn, frameId: state.frameId, still: state.still, size: state.size,
                  camera: state.camera, inputLatency: state.inputLatency, error: state.error,
                  transport: state.transport, inputHopMs: state.inputHopMs,
                  frameHopMs: median(state.frameHops), relayWaitMs: median(state.relayWaits)} : null;
}"""


def run_first_cells(page: Any, count: int, timeout_ms: float) -> None:
    """Run the notebook's first ``count`` cells as a user does: click into the first, Shift+Enter each."""
    page.wait_for_selector(".jp-Notebook .jp-Cell .cm-content", timeout=timeout_ms)
    page.wait_for_selector(".jp-StatusBar-TextItem:has-text('Idle')", timeout=timeout_ms)   # the kernel is up
    page.locator(".jp-Notebook .jp-Cell .cm-content").first.click()
    for _ in range(count):
        page.keyboard.press("Shift+Enter")
