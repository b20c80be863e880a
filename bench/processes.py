"""What the live benchmarks share: child processes with kept output, the coordinator started on
port 0, process CPU from ``/proc``, and the camera turned about its target."""

from __future__ import annotations

import json
import math
import os
import platform
import re
import signal
import subprocess
import sys
import threading
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
#: /proc/PID/stat counts CPU time in these per second
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


class LoggedProcess:
    """A child process (``python ARGS`` in the repository) whose output lines are kept (the last 500)."""

    def __init__(self, args: Sequence[str]) -> None:
        self.process = subprocess.Popen([sys.executable, *args], cwd=REPO, stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, text=True,
                                        env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.lines: deque[str] = deque(maxlen=500)
        self._ended = False
        self._changed = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            with self._changed:
                self.lines.append(line.rstrip("\n"))
                self._changed.notify_all()
        with self._changed:
            self._ended = True
            self._changed.notify_all()

    def wait_for(self, pattern: str, timeout: float) -> re.Match:
        """The first output line matching ``pattern``; RuntimeError (with the output) after ``timeout`` s
        or when the output ends without one."""
        regex = re.compile(pattern)

        def found() -> re.Match | None:
            return next((m for m in map(regex.search, self.lines) if m), None)

        with self._changed:
            self._changed.wait_for(lambda: found() or self._ended or self.process.poll() is not None, timeout)
            match = found()
        if match is None:
            raise RuntimeError(f"no line matching {pattern!r} within {timeout:.0f} s:\n" + "\n".join(self.lines))
        return match

    def stop(self, timeout: float = 20.0) -> int:
        """SIGINT, SIGKILL after ``timeout`` s; the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._reader.join(timeout=5)
        if self.process.stdout is not None:
            self.process.stdout.close()
        return self.process.returncode


def start_coordinator(args: Sequence[str], timeout: float = 60.0) -> tuple[LoggedProcess, str]:
    """``python -m server --port 0 --log-level warning ARGS`` in the repository (ARGS may override
    the log level) and its base URL without the trailing slash, once it printed "Tessera serving on
    URL"; stopped again, RuntimeError with its output, when that takes over ``timeout`` s or it exits."""
    coordinator = LoggedProcess(["-m", "server", "--port", "0", "--log-level", "warning", *args])
    try:
        url = coordinator.wait_for(r"Tessera serving on (http://\S+)", timeout).group(1).rstrip("/")
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


def write_result(path: Path, result: dict[str, Any], argv: Sequence[str] | None) -> None:
    """A benchmark's figures as JSON at ``path``, with the Python version, CPU count and arguments
    (``argv``, or the command line's when None) under ``meta``."""
    meta = {"python": platform.python_version(), "cpus": os.cpu_count(),
            "argv": sys.argv[1:] if argv is None else list(argv)}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({**result, "meta": meta}, indent=2) + "\n")
    print(f"wrote {path}")
