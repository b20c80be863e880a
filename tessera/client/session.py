"""A session from Python: its camera, size, objects, animation and scene, its frames as numpy
images, and its notebook view. Every call is one REST request (or the viewer socket, for
:meth:`Session.frames`); every error a :class:`TesseraError`."""

from __future__ import annotations

import io
import math
import time
from collections.abc import AsyncIterator, Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

import httpx
import numpy as np
from PIL import Image

from tessera.client.connection import Connection
from tessera.client.errors import TesseraError
from tessera.client.frames import ViewSocket, composite, decode_frame, frames_async
from tessera.client.render_jobs import Progress, path_body, run_job
from tessera.client.scene_state import Animation, Objects
from tessera.client.values import SessionInfo, camera_json
from tessera.geometry import Camera
from tessera.wire.mesh_update import MeshError, checked_mesh, pack_mesh

if TYPE_CHECKING:
    from tessera.client.notebook import TesseraView


def orbited(camera: Camera, degrees: float, elevation: float = 0.0) -> Camera:
    """``camera`` with its eye turned ``degrees`` about its up vector through its target (right
    handed: positive turns the eye to its left), then raised ``elevation`` degrees toward up."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (camera.eye, camera.target, camera.up))
    axis = up / np.linalg.norm(up)
    offset = eye - target
    offset = rotate(offset, axis, math.radians(degrees))
    if elevation:
        side = np.cross(axis, offset)
        if np.linalg.norm(side) > 1e-12:
            raised = rotate(offset, side / np.linalg.norm(side), -math.radians(elevation))
            if np.linalg.norm(np.cross(raised, axis)) > 1e-6 * np.linalg.norm(raised):
                offset = raised
    return Camera(tuple((target + offset).tolist()), camera.target, camera.up, camera.fovy_deg, camera.near, camera.far)


def rotate(vector: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """``vector`` (3,) turned ``angle`` radians about unit ``axis`` (Rodrigues)."""
    c, s = math.cos(angle), math.sin(angle)
    return vector * c + np.cross(axis, vector) * s + axis * float(np.dot(axis, vector)) * (1.0 - c)


def fitted(camera: Camera, bounds: np.ndarray, size: tuple[int, int]) -> Camera:
    """``camera`` looking from the same direction at the centre of ``bounds`` (2×3), as far away as
    the bounding sphere needs to fill the narrower field of view of a ``size`` (w, h) frame."""
    lo, hi = np.asarray(bounds, dtype=np.float64)
    center = (lo + hi) / 2.0
    radius = max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-6)
    half = math.radians(camera.fovy_deg) / 2.0
    narrowest = min(half, math.atan(math.tan(half) * size[0] / size[1]))
    direction = np.asarray(camera.eye, dtype=np.float64) - np.asarray(camera.target, dtype=np.float64)
    direction /= np.linalg.norm(direction)
    eye = center + direction * radius / math.sin(narrowest) * 1.05
    return Camera(tuple(eye.tolist()), tuple(center.tolist()), camera.up, camera.fovy_deg)


#: The longest wait ``GET …/frame.png`` takes (its ``timeout``, s).
MAX_FRAME_WAIT_S = 300.0


def frame_of(response: httpx.Response) -> tuple[int, np.ndarray]:
    """A ``frame.png`` answer: its frame id and (h, w, 3) uint8 image."""
    return int(response.headers["x-frame-id"]), np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))


class Session:
    """Session ``id`` of the coordinator ``connection`` (made by :meth:`Tessera.open_session`,
    :meth:`Tessera.session`); ``on_close`` is told when :meth:`close` closed it. A context manager:
    leaving it closes a session this client opened (one with ``on_close``)."""

    def __init__(self, connection: Connection, session_id: str,
                 on_close: Callable[[Session], None] | None = None) -> None:
        self.connection = connection
        self.id = session_id
        self.on_close = on_close
        #: The first frame id that shows every change this object made (camera, size, objects…).
        self.changed_at = 0
        self.objects = Objects(self)
        self.animation = Animation(self)
        self._ready = False

    @property
    def path(self) -> str:
        """The session's routes: ``api/`` for the default session, else ``api/sessions/ID/``."""
        return "api/" if self.id == "default" else f"api/sessions/{quote(self.id, safe='')}/"

    def call(self, method: str, route: str, **options: Any) -> Any:
        return self.connection.call(method, self.path + route, **options)

    def changed(self, answer: dict[str, Any]) -> int:
        """Note an answer's ``frame`` (the first frame id showing a change); returns it."""
        self.changed_at = max(self.changed_at, int(answer["frame"]))
        return int(answer["frame"])

    # ----------------------------------------------------------------- what it is
    def info(self) -> SessionInfo:
        """The session's summary: scene, size, viewers, fps, latency, state…"""
        return SessionInfo.from_json(self.connection.call("GET", f"api/sessions/{quote(self.id, safe='')}"))

    @property
    def scene(self) -> str:
        return self.info().scene

    def stats(self) -> dict[str, Any]:
        """The session's ``/stats``: frame, fps, size, balancer, imbalance, latency_ms, nodes…"""
        return self.call("GET", "stats")

    def wait_ready(self, timeout: float | None = None) -> Session:
        """Wait until a node holds the session's scene (its camera and bounds known); TesseraError
        when the scene failed to load or ``timeout`` (default the client's) passed."""
        deadline = time.monotonic() + (timeout if timeout is not None else self.connection.timeout)
        while not self._ready:
            info = self.info()
            if info.state == "error":
                raise TesseraError(f"the scene {info.scene!r} did not load: {info.summary.get('error')}")
            self._ready = info.state == "ready" and self.call("GET", "camera")["bounds"] is not None
            if not self._ready and time.monotonic() > deadline:
                raise TesseraError(f"the scene {info.scene!r} was not loaded in time (state {info.state})")
            if not self._ready:
                time.sleep(0.05)
        return self

    # ----------------------------------------------------------------- camera
    @property
    def camera(self) -> Camera:
        """The newest camera (set it to a :class:`Camera` or camera JSON)."""
        camera = self.wait_ready().call("GET", "camera")["camera"]
        return Camera.from_json(camera)

    @camera.setter
    def camera(self, camera: Camera | dict[str, Any]) -> None:
        self.set_camera(camera)

    def set_camera(self, camera: Camera | dict[str, Any]) -> int:
        """Set the camera; returns the first frame id that shows it."""
        return self.changed(self.call("PUT", "camera", json=camera_json(camera)))

    @property
    def bounds(self) -> np.ndarray:
        """The scene's axis-aligned bounds, (2, 3) float64: lowest and highest corner."""
        return np.asarray(self.wait_ready().call("GET", "camera")["bounds"], dtype=np.float64)

    def orbit(self, degrees: float, elevation: float = 0.0) -> int:
        """Turn the eye ``degrees`` about the up vector through the target (and raise it
        ``elevation`` degrees); returns the first frame id showing it."""
        return self.set_camera(orbited(self.camera, degrees, elevation))

    def look_at(self, target: Sequence[float], eye: Sequence[float] | None = None,
                up: Sequence[float] | None = None, fovy_deg: float | None = None) -> int:
        """Look at ``target`` from ``eye`` (default: where the eye is), with ``up`` and
        ``fovy_deg`` (default: as they are); returns the first frame id showing it."""
        now = self.camera
        return self.set_camera({"eye": list(eye if eye is not None else now.eye), "target": list(target),
                                "up": list(up if up is not None else now.up),
                                "fovy_deg": fovy_deg if fovy_deg is not None else now.fovy_deg})

    def fit(self) -> int:
        """Frame the whole scene from the current view direction; returns the first frame id showing it."""
        return self.set_camera(fitted(self.camera, self.bounds, self.size))

    # ----------------------------------------------------------------- size
    @property
    def size(self) -> tuple[int, int]:
        """The frame size (w, h px); set it to resize (scaled down to fit ``--max-size``)."""
        width, height = self.info().size
        return width, height

    @size.setter
    def size(self, size: tuple[int, int]) -> None:
        self.changed(self.call("PUT", "size", json={"size": [int(size[0]), int(size[1])]}))

    # ----------------------------------------------------------------- the scene
    def set_scene(self, scene: str, camera: Camera | dict[str, Any] | None = None) -> int:
        """Show library scene ``scene`` (a name, or what :meth:`Tessera.upload` returned) from now
        on, keeping the camera (or from ``camera``). The frames before the new scene's first one
        show the old scene whole, never a mix; returns the first frame id of the new scene."""
        body: dict[str, Any] = {"scene": scene}
        if camera is not None:
            body["camera"] = camera_json(camera)
        self._ready = False
        return self.changed(self.call("PUT", "scene", json=body))

    def update_mesh(self, vertices: Any, faces: Any, normals: Any = None, colors: Any = None) -> int:
        """Show this mesh from now on, in place of the session's scene (or its last mesh): ``vertices``
        N×3 float (scene units), ``faces`` M×3 int indices into them, optional ``normals`` N×3
        (default: smooth, computed by the nodes) and ``colors`` N×3 or N×4 (floats 0–1 or integers
        0–255). Sent as binary arrays, with no upload to the library; the camera is kept. Every frame
        from the returned frame id on shows this mesh (or a newer one) on every tile, those before it
        the one before, never a mix. While the mesh before is not on screen yet the call waits for it,
        so a loop calling it shows every step (a mesh sent from elsewhere meanwhile takes its place).
        TesseraError for arrays of the wrong shape, values that are not finite, indices out of range
        or a mesh over ``--max-upload-mb``."""
        try:
            body = pack_mesh(checked_mesh(vertices, faces, normals, colors))
        except MeshError as exc:
            raise TesseraError(str(exc), what="update_mesh") from None
        self._ready = False
        return self.changed(self.connection.call(
            "PUT", f"api/sessions/{quote(self.id, safe='')}/mesh", content=body,
            headers={"content-type": "application/octet-stream"}))

    # ----------------------------------------------------------------- pictures
    def snapshot(self, still: bool = True, after: int | None = None) -> np.ndarray:
        """The picture as an (h, w, 3) uint8 array: with ``still`` the lossless still the session
        converges to once nothing moves (every sample of the progressive still), else the first
        complete frame; either showing every change this object made (or from frame ``after``)."""
        return self.snapshot_frame(still, after)[1]

    def snapshot_frame(self, still: bool = True, after: int | None = None) -> tuple[int, np.ndarray]:
        """:meth:`snapshot` with the frame's id."""
        self.wait_ready()   # a scene that failed to load is an error with its reason, not a wait for frames
        return frame_of(self.connection.request("GET", self.path + "frame.png", params=self._frame_query(still, after)))

    async def snapshot_async(self, still: bool = True, after: int | None = None) -> np.ndarray:
        """:meth:`snapshot` for asyncio (the wait does not hold the event loop)."""
        return frame_of(await self.connection.request_async("GET", self.path + "frame.png",
                                                            params=self._frame_query(still, after)))[1]

    def _frame_query(self, still: bool, after: int | None) -> dict[str, Any]:
        """``frame.png``'s query: from ``after`` (default: every change made here), still or not,
        the coordinator waiting for it almost as long as this client waits for the answer."""
        params: dict[str, Any] = {"after": self.changed_at if after is None else after,
                                  "timeout": round(min(MAX_FRAME_WAIT_S, max(1.0, 0.9 * self.connection.timeout)), 1)}
        if still:
            params["still"] = "true"
        return params

    def save(self, path: str | Path, still: bool = True) -> Path:
        """Write :meth:`snapshot` to ``path`` (PNG, or any format Pillow knows by its suffix)."""
        path = Path(path)
        Image.fromarray(self.snapshot(still)).save(path)
        return path

    def poster(self, size: tuple[int, int], out: str | Path = "poster.png", *, samples: int | None = None,
               timeout: float | None = None, progress: Progress | None = None) -> Path:
        """Render a poster of the session's picture as it is now, ``size`` = (w, h) px up to
        16384x16384, on the cluster (``samples`` per pixel; default the still's), wait for it and
        write the PNG to ``out``; ``progress(done, total)`` is told as it goes. TesseraError with
        the reason when it fails, or after ``timeout`` s (it is then cancelled)."""
        body: dict[str, Any] = {"size": [int(size[0]), int(size[1])]}
        if samples is not None:
            body["samples"] = samples
        return run_job(self, "posters", body, Path(out), "png", timeout, progress)

    def record(self, path: str | Path | dict[str, Any] | Sequence[Camera | dict[str, Any]] | None = None,
               out: str | Path = "film.mp4", *, orbit: tuple[float, float] | None = None, fps: float | None = None,
               size: tuple[int, int] | None = None, samples: int = 1, timeout: float | None = None,
               progress: Progress | None = None) -> Path:
        """Render a film of the session's scene on the cluster along camera ``path`` (a JSON file of
        the benchmarks' format ``{"dt_ms", "frames"}``, its dict, or a list of cameras) or an
        ``orbit`` = (turns, seconds) around the camera's target, every frame at full detail, at
        ``fps`` (default the path's, or 30), ``size`` (default the session's), ``samples`` per
        pixel; wait for it and write the H.264 MP4 to ``out``. TesseraError as :meth:`poster`."""
        if (path is None) == (orbit is None):
            raise TesseraError("give one of path and orbit")
        body: dict[str, Any] = {"samples": samples}
        if path is not None:
            body["path"] = path_body(path)
        else:
            assert orbit is not None
            body["orbit"] = {"turns": float(orbit[0]), "seconds": float(orbit[1])}
        if fps is not None:
            body["fps"] = float(fps)
        if size is not None:
            body["size"] = [int(size[0]), int(size[1])]
        return run_job(self, "recordings", body, Path(out), "mp4", timeout, progress)

    def frames(self, still_only: bool = False, timeout: float | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """The session's frames as they are published: (frame id, (h, w, 3) uint8 image), each one
        complete (every tile of one instant), newest first when this reader falls behind (frames in
        between are skipped); ``still_only``: only still frames. Stops with TesseraError when the
        session closes, or when no frame came for ``timeout`` s (None: waits as long as it takes).
        Frames render on demand: a session nobody moves publishes no new frame."""
        with ViewSocket(self.connection.url, self.id, self.connection.token, self.connection.timeout) as socket:
            while True:
                try:
                    message = socket.receive(timeout)
                except TimeoutError:
                    raise TesseraError(f"no frame in {timeout} s", what="WS /ws/view") from None
                if isinstance(message, bytes):
                    frame = decode_frame(message)
                    if frame.still or not still_only:
                        yield frame.frame_id, composite(frame)

    def frames_async(self, still_only: bool = False,
                     timeout: float | None = None) -> AsyncIterator[tuple[int, np.ndarray]]:
        """:meth:`frames` for asyncio: ``async for frame_id, image in session.frames_async(): …``."""
        return frames_async(self.connection.url, self.id, self.connection.token, self.connection.timeout, still_only,
                            timeout)

    # ----------------------------------------------------------------- notebook
    def show(self, width: int = 640, height: int = 360, transport: str = "comm") -> TesseraView:
        """A live Jupyter view of the session (an anywidget): the picture, orbit / pan / zoom with
        the mouse and touch, the still badge and a stats line; frames sized to the cell ×
        devicePixelRatio. ``transport="comm"`` (default) carries frames and input through the
        kernel, so the page needs no route to the coordinator; ``"direct"`` opens the coordinator's
        socket from the page (lower latency; the page must reach the coordinator and be one of its
        ``--allowed-origins``)."""
        from tessera.client.notebook import TesseraView

        return TesseraView(self, width, height, transport)

    # ----------------------------------------------------------------- lifetime
    def close(self) -> None:
        """Close the session on the coordinator (its viewers are disconnected)."""
        if self.on_close is not None:
            self.on_close(self)
        self.connection.call("DELETE", f"api/sessions/{quote(self.id, safe='')}")

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.on_close is not None:
            self.close()

    def __repr__(self) -> str:
        return f"Session({self.id!r})"
