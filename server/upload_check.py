"""The check of an uploaded scene file, in a child process of its own with a cap on its memory.

Loading a scene takes far more memory than its file (the 990k-triangle scan, an 18.8 MB PLY, peaks
at 640 MB of address space), so the coordinator never loads an upload itself: it runs
``python -m server.upload_check`` on the file, which sets ``RLIMIT_AS`` (its whole address space,
interpreter and libraries included) to ``--upload-check-memory-mb`` and loads the file as a render
node does (:func:`server.scene_library.check_scene_file`). A file that needs more is refused with
:class:`TooLargeToLoad`; a file that crashes the loader or takes over the time limit is killed and
refused with :class:`NotAScene`; the coordinator and every session go on.

The child prints one JSON line: ``{"triangles": N}``, ``{"refused": REASON}`` or
``{"over_memory": true}``.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import json
import resource
import signal
import subprocess
from collections.abc import Sequence
from pathlib import Path

from server.child_python import child_environment, module_command
from server.scene_library import NotAScene, TooLargeToLoad, check_scene_file

#: One BLAS and OpenMP thread in the child: their per-thread buffers would make the cap depend on
#: the host's core count, and the loader needs none of them.
CHILD_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def checked_triangles(path: Path, name: str, memory_mb: int, timeout_s: float) -> int:
    """The triangles of the scene file at ``path`` (the upload called ``name``), loaded in a child
    process with at most ``memory_mb`` MiB of address space and ``timeout_s`` seconds. Raises
    :class:`TooLargeToLoad` when it needs more memory, :class:`NotAScene` when it does not load, takes
    longer, or the child dies. Blocking: call it from a worker thread."""
    environment = {**child_environment(), **CHILD_ENVIRONMENT}
    command = module_command("server.upload_check", "--memory-mb", str(memory_mb), str(path), name)
    try:
        child = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s, env=environment,
                               stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        raise NotAScene(f"{name!r} took over {timeout_s:g} s to load") from None
    lines = child.stdout.splitlines()
    try:
        answer = json.loads(lines[-1]) if child.returncode == 0 and lines else None
    except json.JSONDecodeError:
        answer = None
    if not isinstance(answer, dict):
        raise NotAScene(f"{name!r}: the check {_how_it_ended(child.returncode)} ({_last_line(child.stderr)})")
    if answer.get("over_memory"):
        raise TooLargeToLoad(f"{name!r} needs more than {memory_mb} MiB to load (--upload-check-memory-mb)")
    if "refused" in answer:
        raise NotAScene(str(answer["refused"]))
    return int(answer["triangles"])


def _how_it_ended(returncode: int) -> str:
    if returncode < 0:
        try:
            return f"was killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"was killed by signal {-returncode}"
    return f"exited {returncode}"


def _last_line(text: str) -> str:
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1][:200] if lines else "no message"


def _caused_by_memory(exc: BaseException | None) -> bool:
    """Whether ``exc`` or an exception it was raised from or while handling is a MemoryError, or an
    OSError of ENOMEM (a memory map refused under the cap); the loader turns any exception into a
    SceneError with its text."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, MemoryError) or (isinstance(exc, OSError) and exc.errno == errno.ENOMEM):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def check_under_cap(path: Path, name: str, memory_bytes: int) -> dict[str, object]:
    """In the child: load ``path`` with the address space capped at ``memory_bytes``; the answer
    to print. The cap is lifted again (it is the soft limit) before answering."""
    for module in ("trimesh", "laspy", "lazrs"):   # the loaders import them on first use: not under the cap
        importlib.import_module(module)
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    capped = memory_bytes if hard == resource.RLIM_INFINITY else min(memory_bytes, hard)
    resource.setrlimit(resource.RLIMIT_AS, (capped, hard))
    try:
        return {"triangles": check_scene_file(path, name)}
    except NotAScene as exc:
        return {"over_memory": True} if _caused_by_memory(exc) else {"refused": str(exc)}
    except MemoryError:
        return {"over_memory": True}
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m server.upload_check",
                                     description="Load an uploaded scene file as a render node does, with capped "
                                                 "memory; print its triangles or why it does not load, as JSON.")
    parser.add_argument("--memory-mb", type=int, required=True, help="cap on the address space, MiB")
    parser.add_argument("path", type=Path, help="the scene file")
    parser.add_argument("name", help="the scene's name, used in messages in place of the path")
    args = parser.parse_args(argv)
    print(json.dumps(check_under_cap(args.path, args.name, args.memory_mb << 20)))


if __name__ == "__main__":
    main()
