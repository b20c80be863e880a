"""Posters and films from Python (issue 35): :meth:`Session.poster` and :meth:`Session.record` start
a render job on the cluster, wait for it (saying how far it is, if asked) and write its file; a job
that fails raises TesseraError with the coordinator's reason, and one interrupted (Ctrl-C, a
timeout) is cancelled on the coordinator."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

from tessera.client.connection import Connection
from tessera.client.errors import TesseraError
from tessera.client.values import camera_json
from tessera.geometry import Camera


class JobSession(Protocol):
    """What a job needs of its :class:`tessera.client.session.Session`."""

    connection: Connection

    @property
    def path(self) -> str: ...

    def call(self, method: str, route: str, **options: Any) -> Any: ...

#: How often a job's state is asked while waiting (s).
POLL_S = 0.25
#: ``progress(done, total)``: told as a job goes on (a film's frames, a poster's piece samples).
Progress = Callable[[int, int], None]


def path_body(path: str | Path | Mapping[str, Any] | Sequence[Camera | dict[str, Any]]) -> dict[str, Any]:
    """A camera path as the recordings route takes it (``{"dt_ms", "frames"}``) from a JSON file of
    that format, its dict, or a list of cameras (camera JSON or :class:`Camera`)."""
    data: Any = path
    if isinstance(path, str | Path):
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, ValueError) as exc:
            raise TesseraError(f"camera path file {path}: {exc}") from None
    if isinstance(data, Mapping):
        return {"dt_ms": data.get("dt_ms", 33.3), "frames": [camera_json(c) for c in data.get("frames", [])]}
    return {"frames": [camera_json(camera) for camera in data]}


def run_job(session: JobSession, route: str, body: dict[str, Any], out: Path, suffix: str,
            timeout: float | None, progress: Progress | None) -> Path:
    """Start a job at ``route`` (``posters``, ``recordings``) with ``body``, wait until it is done
    (TesseraError when it fails, or after ``timeout`` s, cancelling it), write its file to ``out``."""
    job_id = session.call("POST", route, json=body)["id"]
    deadline = None if timeout is None else time.monotonic() + timeout
    noun = route.rstrip("s")
    try:
        while True:
            state = session.call("GET", f"{route}/{job_id}")
            if progress is not None:
                progress(int(state["done"]), int(state["total"]))
            if state["state"] == "done":
                break
            if state["state"] in ("error", "cancelled"):
                raise TesseraError(f"the {noun} {job_id} ended ({state['state']}): {state.get('reason')}")
            if deadline is not None and time.monotonic() > deadline:
                raise TesseraError(f"the {noun} {job_id} was not done within {timeout:g} s "
                                   f"({state['done']}/{state['total']}); it was cancelled")
            time.sleep(POLL_S)
    except BaseException:
        _cancel(session, route, job_id)
        raise
    response = session.connection.request("GET", session.path + f"{route}/{job_id}.{suffix}")
    out = Path(out)
    out.write_bytes(response.content)
    return out


def _cancel(session: JobSession, route: str, job_id: str) -> None:
    """Cancel the job if it is still under way (nothing when it is over or cannot be reached)."""
    try:
        state = session.call("GET", f"{route}/{job_id}")
        if state["state"] in ("queued", "rendering"):
            session.call("DELETE", f"{route}/{job_id}")
    except TesseraError:
        pass
