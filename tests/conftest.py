"""Shared test fixtures: where the real scenes are, one timeout scale, the session's GL context,
real coordinator processes.

Integration tests start real processes on port 0 and wait for readiness; every timeout is a
multiple of ``TIMEOUT_SCALE`` (raise ``TESSERA_TEST_TIMEOUT_SCALE`` on slow machines).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import moderngl
import pytest

from node.gl.context import create_gl_context

REPO = Path(__file__).resolve().parents[1]
SCENES = REPO.parent / "shared" / "scenes"
TIMEOUT_SCALE = float(os.environ.get("TESSERA_TEST_TIMEOUT_SCALE", "1.0"))
PYTHON = sys.executable


def seconds(value: float) -> float:
    """A timeout scaled by TIMEOUT_SCALE."""
    return value * TIMEOUT_SCALE


def scene_path(relative: str) -> Path:
    """Path of a real scene under ../shared/scenes; fails the test clearly when it is missing."""
    path = SCENES / relative
    if not path.exists():
        pytest.fail(f"scene {relative} not found: the tests read real scenes from {SCENES} "
                    "(the shared/ folder beside the checkout)")
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


@dataclass
class RunningProcess:
    """A child process whose combined output is collected line by line in the background (the last
    2000 lines); ``tracebacks`` counts the lines with "Traceback" in all of it, and the first
    traceback is kept in ``first_traceback``."""

    process: subprocess.Popen
    lines: deque = field(default_factory=lambda: deque(maxlen=2000))
    tracebacks: int = 0
    first_traceback: list[str] = field(default_factory=list)
    _ended: bool = False

    def __post_init__(self) -> None:
        self._changed = threading.Condition()
        self._reader = threading.Thread(target=self._pump, daemon=True)
        self._reader.start()

    def _pump(self) -> None:
        """Collect output lines, waking waiters on each line and when the output ends."""
        assert self.process.stdout is not None
        for line in self.process.stdout:
            with self._changed:
                self.lines.append(line.rstrip("\n"))
                self.tracebacks += "Traceback" in line
                if self.tracebacks == 1 and len(self.first_traceback) < 60:
                    self.first_traceback.append(line.rstrip("\n"))
                self._changed.notify_all()
        with self._changed:
            self._ended = True
            self._changed.notify_all()

    def wait_for_line(self, pattern: str, timeout: float) -> re.Match:
        """The first output line matching ``pattern``, waiting for new lines until ``timeout`` s or
        the end of the output."""
        regex = re.compile(pattern)

        def found() -> re.Match | None:
            return next((m for m in map(regex.search, self.lines) if m), None)

        with self._changed:
            self._changed.wait_for(lambda: found() or self._ended, timeout)
            match = found()
        if match:
            return match
        raise AssertionError(f"no line matching {pattern!r} within {timeout:.0f}s; output:\n" + self.output())

    def output(self) -> str:
        with self._changed:
            return "\n".join(self.lines)

    def stop(self, timeout: float = 20.0) -> int:
        """SIGINT (like Ctrl-C), then SIGKILL if it does not exit in time; returns the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=seconds(timeout))
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._reader.join(timeout=5)
        if self.process.stdout is not None:
            self.process.stdout.close()
        return self.process.returncode


def start_process(args: list[str], env: dict[str, str] | None = None) -> RunningProcess:
    full_env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
    process = subprocess.Popen(
        args, cwd=REPO, env=full_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        start_new_session=True,
    )
    return RunningProcess(process)


@dataclass
class Coordinator:
    """A running ``python -m server`` and the base URL it printed."""

    proc: RunningProcess
    url: str

    @property
    def ws_url(self) -> str:
        return self.url.replace("http://", "ws://", 1).rstrip("/")


def start_coordinator(*args: str, env: dict[str, str] | None = None) -> Coordinator:
    """Start the coordinator on port 0 and wait until it prints its URL."""
    proc = start_process([PYTHON, "-m", "server", "--port", "0", *args], env=env)
    match = proc.wait_for_line(r"Tessera serving on (http://\S+)", seconds(60))
    return Coordinator(proc, match.group(1).rstrip("/"))


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
