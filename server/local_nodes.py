"""``--local-nodes N``: render node processes on this machine, stopped with the coordinator.

The nodes share this machine's cores: each gets ``LP_NUM_THREADS`` = cores / N (unless set), so
that N llvmpipe renderers do not fight over more threads than there are cores.
They import this coordinator's own ``node`` package (:mod:`server.child_python`), whatever the
working folder holds. Each child gets PR_SET_PDEATHSIG so that it dies with the coordinator even if the coordinator is
killed outright; a normal exit (Ctrl-C) terminates and reaps them.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import signal
import subprocess

from server.child_python import child_environment, module_command

log = logging.getLogger("tessera.server")
PR_SET_PDEATHSIG = 1
#: How long after start-up the coordinator waits for its local nodes to join before it cuts
#: sort-last shares over those that did (s); they join in 2-3 s on a quiet 2-core machine.
LOCAL_NODES_JOIN_S = 20.0


def _die_with_parent() -> None:
    with contextlib.suppress(OSError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def llvmpipe_threads_per_node(count: int) -> int:
    """Mesa llvmpipe raster threads for each of ``count`` nodes sharing this machine's cores, so
    that local nodes do not oversubscribe the CPU (ignored by GPU drivers)."""
    return max(1, (os.cpu_count() or 1) // count)


class LocalNodes:
    def __init__(self) -> None:
        self.processes: list[subprocess.Popen] = []

    def spawn(self, count: int, coordinator_url: str, token: str | None, slowdowns: tuple[float, ...]) -> None:
        for index in range(count):
            args = module_command("node", "--coordinator", coordinator_url, "--name", f"local-{index + 1}")
            if index < len(slowdowns) and slowdowns[index] != 1.0:
                args += ["--slowdown", str(slowdowns[index])]
            env = child_environment()
            if token:
                env["TESSERA_TOKEN"] = token
            env.setdefault("LP_NUM_THREADS", str(llvmpipe_threads_per_node(count)))
            self.processes.append(subprocess.Popen(args, env=env, preexec_fn=_die_with_parent))
        log.info("spawned %d local render nodes (pids %s)", count, [p.pid for p in self.processes])

    def stop(self, timeout: float = 10.0) -> None:
        for process in self.processes:
            if process.poll() is None:
                process.terminate()
        for process in self.processes:
            try:
                process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        self.processes.clear()
