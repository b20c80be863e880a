"""What the live benchmarks and the tests' fixtures share: child processes with kept output, the
coordinator started on port 0, process CPU from ``/proc``, and the camera turned about its target."""

from __future__ import annotations

import contextlib
import json
import math
import os
import platform
import re
import shlex
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
PYTHON = sys.executable
#: /proc/PID/stat counts CPU time in these per second
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
#: output lines a LoggedProcess keeps
KEPT_LINES = 2000
#: lines of its first traceback a LoggedProcess keeps
TRACEBACK_LINES = 60
#: how long a process that exited may stay silent before waiting for a line of it gives up, s
EXITED_SILENCE_S = 0.5


class LoggedProcess:
    """A child process running ``command`` in the repository (Python unbuffered, ``env`` added to
    this process's environment), its stdout and stderr read line by line on a thread of its own:
    the last :data:`KEPT_LINES` lines kept in ``lines``, each line written to ``log_path`` as it
    comes when one is given, the lines with "Traceback" counted in ``tracebacks`` and the first
    traceback's first :data:`TRACEBACK_LINES` lines kept in ``first_traceback``.

    ``new_session``: the child gets a session of its own, so a Ctrl-C on the terminal reaches only
    this process, and the child just what :meth:`stop` sends. ``label`` names it in errors (default:
    the command line). ``cwd``: where it runs (default the repository); ``environ``: the environment
    ``env`` is added to (default this process's)."""

    def __init__(self, command: Sequence[str], *, label: str = "", env: Mapping[str, str] | None = None,
                 log_path: Path | None = None, new_session: bool = False, stop_timeout: float = 20.0,
                 cwd: Path = REPO, environ: Mapping[str, str] | None = None) -> None:
        self.label = label or shlex.join(command)
        self.stop_timeout = stop_timeout
        self.lines: deque[str] = deque(maxlen=KEPT_LINES)
        self.tracebacks = 0
        self.first_traceback: list[str] = []
        #: whether :meth:`stop` had to SIGKILL it
        self.killed = False
        self._ended = False
        self._changed = threading.Condition()
        self._log = log_path.open("w") if log_path is not None else None
        base = os.environ if environ is None else environ
        self.process = subprocess.Popen(list(command), cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                        text=True, env={**base, "PYTHONUNBUFFERED": "1", **(env or {})},
                                        start_new_session=new_session)
        self._reader = threading.Thread(target=self._read, name=f"output of {self.label}", daemon=True)
        self._reader.start()

    @property
    def pid(self) -> int:
        return self.process.pid

    def _read(self) -> None:
        """Keep and log each output line, waking waiters on each line and when the output ends."""
        assert self.process.stdout is not None
        with contextlib.suppress(ValueError):  # stop() closed the pipe that the process's children still hold
            for raw in self.process.stdout:
                line = raw.rstrip("\n")
                if self._log is not None:
                    self._log.write(raw)
                    self._log.flush()
                with self._changed:
                    self.lines.append(line)
                    self.tracebacks += "Traceback" in line
                    if self.tracebacks == 1 and len(self.first_traceback) < TRACEBACK_LINES:
                        self.first_traceback.append(line)
                    self._changed.notify_all()
        if self._log is not None:
            self._log.close()
        with self._changed:
            self._ended = True
            self._changed.notify_all()

    def wait_for_line(self, pattern: str, timeout: float) -> re.Match:
        """The first kept output line matching ``pattern``, waiting up to ``timeout`` s for one;
        RuntimeError with the output when none came by then, or the output ended, or the process
        exited and printed nothing more for :data:`EXITED_SILENCE_S` (children it started may hold
        its output open)."""
        regex = re.compile(pattern)
        deadline = time.monotonic() + max(0.0, timeout)
        with self._changed:
            while (match := next((m for m in map(regex.search, self.lines) if m), None)) is None and not self._ended:
                left = deadline - time.monotonic()
                exited = self.process.poll() is not None
                if left <= 0 or (not self._changed.wait(min(left, EXITED_SILENCE_S)) and exited):
                    break
        if match is None:
            raise RuntimeError(f"{self.label}: no line matching {pattern!r} within {timeout:.0f} s; output:\n"
                               + self.output())
        return match

    def output(self) -> str:
        """The kept output lines."""
        with self._changed:
            return "\n".join(self.lines)

    def stop(self, signum: int = signal.SIGINT, timeout: float | None = None) -> int:
        """Send ``signum`` (SIGINT: as Ctrl-C) unless it has exited, SIGKILL if it has not exited
        ``timeout`` s later (default ``stop_timeout``; ``killed`` then says so); the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(signum)
            try:
                self.process.wait(timeout=self.stop_timeout if timeout is None else timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
                self.killed = True
        self._reader.join(timeout=5)
        if self.process.stdout is not None:
            self.process.stdout.close()
        return self.process.returncode


def start_coordinator(args: Sequence[str], *, port: int = 0, log_level: str | None = None, timeout: float = 60.0,
                      env: Mapping[str, str] | None = None, log_path: Path | None = None, new_session: bool = False,
                      stop_timeout: float = 20.0) -> tuple[LoggedProcess, str]:
    """``python -m server --port PORT [--log-level LEVEL] ARGS`` as a :class:`LoggedProcess` labelled
    "coordinator" (``env``, ``log_path``, ``new_session``, ``stop_timeout`` are its own), and its base
    URL without the trailing slash, once it printed "Tessera serving on URL"; stopped again, and
    RuntimeError with its output, when that takes over ``timeout`` s or it exits first."""
    level = [] if log_level is None else ["--log-level", log_level]
    coordinator = LoggedProcess([PYTHON, "-m", "server", "--port", str(port), *level, *args], label="coordinator",
                                env=env, log_path=log_path, new_session=new_session, stop_timeout=stop_timeout)
    try:
        url = coordinator.wait_for_line(r"Tessera serving on (http://\S+)", timeout).group(1).rstrip("/")
    except BaseException:
        coordinator.stop()
        raise
    return coordinator, url


def process_tree(pid: int) -> list[int]:
    """``pid`` and its descendants, from /proc."""
    parents: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as stat:
                    parents[int(entry)] = int(stat.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
    tree, frontier = [pid], [pid]
    while frontier:
        children = [child for child, parent in parents.items() if parent in frontier]
        tree += children
        frontier = children
    return tree


def local_node_pids(coordinator_pid: int) -> list[int]:
    """The coordinator's local node processes: its direct children running ``-m node`` (not what
    they start in turn, nor a short-lived helper such as ``ldconfig``)."""
    pids = []
    for pid in process_tree(coordinator_pid)[1:]:
        try:
            command = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
            parent = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1]
        except (OSError, IndexError):
            continue
        if parent == str(coordinator_pid) and b"node" in command:
            pids.append(pid)
    return pids


def cpu_seconds(pids: Sequence[int]) -> float:
    """User + system CPU seconds of ``pids`` (/proc utime + stime; processes that ended count 0)."""
    total = 0
    for pid in pids:
        try:
            with open(f"/proc/{pid}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()
            total += int(fields[11]) + int(fields[12])
        except (OSError, ValueError, IndexError):
            continue
    return total / CLOCK_TICKS


def orbit(camera: dict[str, Any], angle: float) -> dict[str, Any]:
    """``camera`` (a JSON camera: ``eye``, ``target``, …) with its eye turned by ``angle`` radians
    about the vertical axis through its target; the height and the other fields unchanged."""
    eye, target = np.asarray(camera["eye"], dtype=float), np.asarray(camera["target"], dtype=float)
    x, z = (eye - target)[0], (eye - target)[2]
    c, s = math.cos(angle), math.sin(angle)
    return {**camera, "eye": [float(target[0] + c * x + s * z), float(eye[1]), float(target[2] - s * x + c * z)]}


def show_result(text: str, result: dict[str, Any], path: Path | None, argv: Sequence[str] | None) -> None:
    """Print a benchmark's table ``text``, and write its ``result`` as JSON at ``path`` if given."""
    print(text)
    if path is not None:
        write_result(path, result, argv)


def write_result(path: Path, result: dict[str, Any], argv: Sequence[str] | None) -> None:
    """A benchmark's figures as JSON at ``path``, with the Python version, CPU count and arguments
    (``argv``, or the command line's when None) under ``meta``."""
    meta = {"python": platform.python_version(), "cpus": os.cpu_count(),
            "argv": sys.argv[1:] if argv is None else list(argv)}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({**result, "meta": meta}, indent=2) + "\n")
    print(f"wrote {path}")
