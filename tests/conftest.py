"""Shared test fixtures: where the real scenes are, one timeout scale, the session's GL context,
real coordinator processes.

Integration tests start real processes on port 0 and wait for readiness; every timeout is a
multiple of ``TIMEOUT_SCALE`` (raise ``TESSERA_TEST_TIMEOUT_SCALE`` on slow machines).
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import moderngl
import pytest

from bench import processes
from bench.processes import PYTHON, REPO, LoggedProcess
from node.gl.context import create_gl_context

#: The real scenes: $TESSERA_TEST_SCENES (scripts/test sets it), else ../shared/scenes.
SCENES = Path(os.environ.get("TESSERA_TEST_SCENES") or REPO.parent / "shared" / "scenes")
#: The scene cache every node and render-once of a test run uses (inherited by the processes it
#: starts): a folder of its own, so runs (of other checkouts too) never share entries.
#: Moving frames are compared with ``--render-once --interactive`` (full detail) in many tests: the
#: coordinators they start draw moving frames at full detail unless a test asks for levels of detail.
os.environ.setdefault("TESSERA_LOD_ERROR_PX", "0")
if "TESSERA_SCENE_CACHE_DIR" not in os.environ:
    os.environ["TESSERA_SCENE_CACHE_DIR"] = tempfile.mkdtemp(prefix="tessera-test-scene-cache-")
    atexit.register(shutil.rmtree, os.environ["TESSERA_SCENE_CACHE_DIR"], ignore_errors=True)
TIMEOUT_SCALE = float(os.environ.get("TESSERA_TEST_TIMEOUT_SCALE", "1.0"))


#: The user's data folder of the coordinators the tests start (where uploads go without --data-dir):
#: one of the test run's own, never the user's.
DATA_HOME = Path(tempfile.mkdtemp(prefix="tessera-test-data-"))
atexit.register(shutil.rmtree, DATA_HOME, ignore_errors=True)


def seconds(value: float) -> float:
    """A timeout scaled by TIMEOUT_SCALE."""
    return value * TIMEOUT_SCALE


def scene_path(relative: str) -> Path:
    """Path of a real scene under SCENES; fails the test clearly when it is missing."""
    path = SCENES / relative
    if not path.exists():
        pytest.fail(f"scene {relative} not found: the tests read real scenes from {SCENES} "
                    "(../shared/scenes, else $TESSERA_TEST_SCENES); scripts/fetch-scenes DIR fetches them")
    return path


@pytest.fixture(scope="session")
def gl_context() -> Iterator[moderngl.Context]:
    """The test session's one GL context: the only place context creation should happen."""
    context = create_gl_context()
    yield context
    context.release()


@pytest.fixture(scope="module")
def ctx(gl_context: moderngl.Context) -> Iterator[moderngl.Context]:
    """The session's GL context, made current for a test module and its module fixtures: code under
    test that makes and releases a context of its own on this thread (a benchmark's ``main``)
    leaves that one current."""
    with gl_context:
        yield gl_context


def start_process(args: list[str], env: dict[str, str] | None = None) -> LoggedProcess:
    """``args`` (a command line) as a child process in a session of its own (a Ctrl-C on pytest's
    terminal does not reach it), its output kept; :meth:`LoggedProcess.stop` waits a scaled 20 s."""
    return LoggedProcess(args, env=env, new_session=True, stop_timeout=seconds(20))


@dataclass
class Coordinator:
    """A running ``python -m server`` and the base URL it printed."""

    proc: LoggedProcess
    url: str

    @property
    def ws_url(self) -> str:
        return self.url.replace("http://", "ws://", 1).rstrip("/")


def start_coordinator(*args: str, env: dict[str, str] | None = None, port: int = 0) -> Coordinator:
    """``python -m server --port PORT ARGS`` (port 0: one the system picks) as :func:`start_process`
    starts a process, once it printed its URL (a scaled 60 s at most); its user data folder is
    :data:`DATA_HOME` unless ``env`` names another."""
    env = {"XDG_DATA_HOME": str(DATA_HOME), **(env or {})}
    return Coordinator(*processes.start_coordinator(args, port=port, timeout=seconds(60), env=env, new_session=True,
                                                   stop_timeout=seconds(20)))


@pytest.fixture
def coordinator_factory():
    """Start coordinators with given CLI args; all are stopped at teardown."""
    started: list[Coordinator] = []

    def factory(*args: str, env: dict[str, str] | None = None) -> Coordinator:
        coordinator = start_coordinator(*args, env=env)
        started.append(coordinator)
        return coordinator

    yield factory
    for coordinator in started:
        coordinator.proc.stop()


@pytest.fixture
def node_factory(coordinator_factory):
    """Start render nodes joining a coordinator: ``python -m node --coordinator WS_URL/ws/node --name
    NAME ARGS``, each a process of its own; all are stopped at teardown, before the coordinators."""
    started: list[LoggedProcess] = []

    def factory(coordinator: Coordinator, name: str, *args: str) -> LoggedProcess:
        node = start_process([PYTHON, "-m", "node", "--coordinator", f"{coordinator.ws_url}/ws/node", "--name", name,
                              *args])
        started.append(node)
        return node

    yield factory
    for node in started:
        node.stop()
