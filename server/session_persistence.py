"""The sessions across restarts and idle time: :class:`SessionPersistence`, the part of
:class:`server.service.RenderService` that writes every session to ``--data-dir`` (and the mesh
step a session shows, issue 33: ``meshes/SESSION_ID.tmsh``), opens them again when the coordinator
starts, and closes sessions nobody used for ``--session-idle-timeout-s``."""

from __future__ import annotations

import logging
import re
import time
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

from server.mesh_updates import MeshUpdates
from server.sessions import Session
from tessera.balancers import create_balancer
from tessera.decomposition.wall_cells import WallLayout
from tessera.geometry import Camera
from tessera.scheduling.frame_jobs import DEFAULT_SESSION
from tessera.wire.mesh_update import MeshError, is_mesh_spec, mesh_header

if TYPE_CHECKING:
    from server.render_jobs import RenderJobs
    from server.session_store import SessionStore
    from server.settings import Settings
    from tessera.scheduling.job_scheduler import JobScheduler

log = logging.getLogger("tessera.server")

#: What a session id is made of (``secrets.token_urlsafe``, or ``default``): safe as a file name.
SESSION_ID = re.compile(r"[A-Za-z0-9_-]{1,64}")


class SessionPersistence:
    """Saving, restoring and closing sessions; mixed into :class:`server.service.RenderService`,
    which owns the attributes named below."""

    settings: Settings
    scheduler: JobScheduler
    jobs: RenderJobs
    default: Session
    sessions: dict[str, Session]
    session_store: SessionStore | None
    changed_sessions: bool
    _session_writer: ThreadPoolExecutor
    _watch_keys: dict[str, str]
    _sessions_opened: int
    meshes: MeshUpdates
    #: The spec of each session's mesh step written to ``--data-dir`` last.
    _meshes_saved: dict[str, str]

    if TYPE_CHECKING:
        def _open(self, session: Session, size: tuple[int, int] | None, camera: Camera | None,
                  fetch: tuple[str, str] | None) -> Session: ...

        def apply(self) -> None: ...

        def allow_for_shown_scenes(self) -> None: ...

    def save_sessions(self) -> Future[None] | None:
        """Write every session to ``--data-dir`` (nothing without one) on the writer thread, off the
        event loop (the file is fsynced); writes happen in the order asked."""
        if self.session_store is None:
            return None
        records = [{**s.record(), "jobs": [j.record() for j in self.jobs.of_session(s.id)]}
                   for s in self.sessions.values()]
        self.changed_sessions = False
        path, store = self.session_store.path, self.session_store
        steps = self.meshes.steps_shown()   # each session's last mesh step, written when it changed
        changed = {i: step.data for i, step in steps.items() if self._meshes_saved.get(i) != step.spec}
        self._meshes_saved = {i: step.spec for i, step in steps.items()}

        def report(done: Future[None]) -> None:
            if done.exception() is not None:
                log.error("cannot save the sessions to %s: %s", path, done.exception())

        def save() -> None:   # the meshes first: the sessions file never names a mesh not written
            store.save_meshes(changed, set(steps))
            store.save(records)

        written = self._session_writer.submit(save)
        written.add_done_callback(report)
        return written

    def _restore_sessions(self) -> None:
        """The sessions ``--data-dir`` held when the coordinator stopped, under their ids and keys."""
        assert self.session_store is not None
        for record in self.session_store.load():
            try:
                self._restore(record)
            except (KeyError, TypeError, ValueError) as exc:   # CameraError is a ValueError
                log.error("session %s… not restored: %s", str(record.get("id"))[:6], exc)

    def _restore(self, record: dict[str, Any]) -> None:
        camera = None if record.get("camera") is None else Camera.from_json(record["camera"])
        if record["id"] == DEFAULT_SESSION:
            session = self.default
            if camera is not None:
                self.scheduler.set_camera(camera, time.monotonic())
        else:
            if is_mesh_spec(str(record["scene"])):
                self._restore_mesh(str(record["id"]), str(record["scene"]))
            wall = None if record.get("wall") is None else WallLayout.from_json(record["wall"])
            session = Session(self, str(record["id"]), str(record["scene"]), str(record["name"]),
                              label=str(record["label"]), wall=wall)
            session.watch_key = str(record["watch_key"])
            fetch = record.get("fetch")
            self._open(session, (int(record["size"][0]), int(record["size"][1])), camera,
                       None if fetch is None else (str(fetch[0]), str(fetch[1])))
            self._sessions_opened = max(self._sessions_opened, int(record["label"]))
        balancer = record.get("balancer")
        if balancer is not None:
            self.scheduler.set_balancer(create_balancer(balancer["name"], balancer["params"]), time.monotonic(),
                                        session.id)
        session.pending_state = record.get("scene_state")
        session.restore_clip(record.get("clip"), record.get("annotations"))
        self.jobs.restore(session.id, record.get("jobs"))
        log.info("session %s… restored: %s", session.id[:6], session.name)

    def _restore_mesh(self, session_id: str, spec: str) -> None:
        """The last mesh step of session ``session_id``, ``spec``, as saved; ValueError when it was not."""
        assert self.session_store is not None
        data = self.session_store.load_mesh(session_id) if SESSION_ID.fullmatch(session_id) else None
        try:
            if data is None or mesh_header(data)[0].get("scene") != spec:
                raise ValueError(f"its mesh {spec} was not saved")
        except MeshError as exc:
            raise ValueError(f"its mesh {spec} does not read: {exc}") from None
        self.meshes.restore(session_id, spec, data)
        self._meshes_saved[session_id] = spec

    def close_session(self, session: Session, reason: str = "session closed") -> None:
        """Close ``session`` (not the default one): its frames are dropped, its viewers told."""
        if session is self.default or self.sessions.pop(session.id, None) is None:
            return
        self._watch_keys.pop(session.watch_key, None)
        self.changed_sessions = True
        self.jobs.session_closed(session.id)
        self.scheduler.remove_session(session.id, time.monotonic())
        self.allow_for_shown_scenes()
        for slot in list(session.viewers.slots):
            slot.close(4404, reason)
        self.apply()
        log.info("session %s… closed: %s", session.id[:6], reason)

    def _collect_idle_sessions(self, now: float) -> None:
        """Close sessions no viewer and no API call used for ``--session-idle-timeout-s``."""
        limit = self.settings.session_idle_timeout_s
        for session in [s for s in self.sessions.values() if s is not self.default and s.idle_for(now) > limit]:
            self.close_session(session, f"idle for over {limit:g} s")
