"""``Tessera(url, token=None)``: a coordinator as Python sees it — its scene library, uploads,
sessions and statistics over the REST API (httpx). Every error is a :class:`TesseraError` with
the coordinator's reason."""

from __future__ import annotations

import contextlib
import io
import os
from typing import TYPE_CHECKING, Any

from tessera.client.connection import DEFAULT_TIMEOUT_S, Connection
from tessera.client.errors import TesseraError
from tessera.client.meshes import MeshSource, upload_body
from tessera.client.session import Session
from tessera.client.values import SceneInfo, SessionInfo, camera_json
from tessera.geometry import Camera

if TYPE_CHECKING:
    from tessera.client.notebook import TesseraView

#: The coordinator ``Tessera()`` talks to when given no URL (``$TESSERA_URL``, else this).
DEFAULT_URL = "http://127.0.0.1:8000"


class Tessera:
    """A Tessera coordinator at ``url`` (default ``$TESSERA_URL`` or http://127.0.0.1:8000; a path
    prefix behind a proxy is kept), presenting ``token`` (default ``$TESSERA_TOKEN``) when it has
    one. A context manager: leaving it closes the sessions it opened and its connections.

    >>> with Tessera("http://127.0.0.1:8000") as tessera:
    ...     with tessera.open_session("builtin:cluster", size=(640, 360)) as session:
    ...         session.orbit(30)
    ...         session.save("shot.png")
    """

    def __init__(self, url: str | None = None, token: str | None = None, timeout: float = DEFAULT_TIMEOUT_S) -> None:
        self.connection = Connection(url or os.environ.get("TESSERA_URL") or DEFAULT_URL,
                                     token if token is not None else os.environ.get("TESSERA_TOKEN") or None, timeout)
        self.url = self.connection.url
        self._opened: list[Session] = []

    def call(self, method: str, path: str, **options: Any) -> Any:
        """``method`` ``path`` (``api/…``): the coordinator's JSON answer (:meth:`Connection.call`)."""
        return self.connection.call(method, path, **options)

    # ----------------------------------------------------------------- the library
    def scenes(self) -> list[SceneInfo]:
        """Every scene a session may show."""
        return [SceneInfo(str(s["name"]), str(s["format"]), int(s["bytes"])) for s in self.call("GET", "api/scenes")]

    def upload(self, source: MeshSource, name: str | None = None) -> str:
        """Add a scene to the library: a file (``path``), a ``trimesh.Trimesh`` / ``Scene`` or arrays
        ``(vertices, faces[, normals[, colors]])`` (N×3 float, M×3 int, N×3 float, N×3|4 uint8 or
        float 0–1), the last two written to a GLB in memory. Returns the scene's name
        (``upload/FILE``). A mesh is named by its content unless ``name`` is given, so uploading one
        twice gives the same scene; a file name already taken is refused (409)."""
        filename, data = upload_body(source, name)
        files = {"file": (filename, io.BytesIO(data), "application/octet-stream")}
        try:
            return str(self.call("POST", "api/scenes", files=files)["name"])
        except TesseraError as exc:
            if exc.status == 409 and name is None and not isinstance(source, (str, os.PathLike)):
                return f"upload/{filename}"   # the same content, uploaded before
            raise

    # ----------------------------------------------------------------- sessions
    def sessions(self) -> list[SessionInfo]:
        """Every open session."""
        return [SessionInfo.from_json(s) for s in self.call("GET", "api/sessions")]

    def open_session(self, scene: str, size: tuple[int, int] | None = None,
                     camera: Camera | dict[str, Any] | None = None) -> Session:
        """A new session showing library scene ``scene`` (a name of :meth:`scenes`, or what
        :meth:`upload` returned) at ``size`` (w, h px; default the coordinator's ``--size``) from
        ``camera`` (default: one framing the scene). Closed by :meth:`Session.close`, by leaving
        it as a context manager, or when this client closes."""
        body: dict[str, Any] = {"scene": scene}
        if size is not None:
            body["size"] = [int(size[0]), int(size[1])]
        if camera is not None:
            body["camera"] = camera_json(camera)
        created = self.call("POST", "api/sessions", json=body)
        session = Session(self.connection, str(created["id"]), on_close=self._forget)
        self._opened.append(session)
        return session

    def session(self, session_id: str) -> Session:
        """Session ``session_id`` (opened elsewhere: the id in its viewer link); ``"default"`` is
        the coordinator's default session. Not closed when this client closes."""
        session = Session(self.connection, session_id)
        session.info()   # TesseraError (404) when there is no such session
        return session

    def stats(self) -> dict[str, Any]:
        """``GET /api/stats``: frame, fps, size, balancer, imbalance, latency_ms, nodes, sessions…"""
        return self.call("GET", "api/stats")

    def view(self, scene: str, width: int = 640, height: int = 360, transport: str = "comm",
             camera: Camera | dict[str, Any] | None = None) -> TesseraView:
        """A notebook view (:meth:`Session.show`) of a new session showing ``scene``."""
        return self.open_session(scene, camera=camera).show(width, height, transport)

    # ----------------------------------------------------------------- lifetime
    def _forget(self, session: Session) -> None:
        if session in self._opened:
            self._opened.remove(session)

    def close(self) -> None:
        """Close the sessions this client opened, then its connections."""
        for session in list(self._opened):
            with contextlib.suppress(TesseraError):   # closed elsewhere, or the coordinator is gone
                session.close()
        self.connection.close()

    def __enter__(self) -> Tessera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Tessera({self.url!r})"
