"""Frames as the viewer gets them, for Python: the session's viewer socket (``WS /ws/view``) and
its ``TFRM`` messages composited into images (:mod:`tessera.wire.protocol`, :mod:`tessera.wire.codec`)."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from typing import Any
from urllib.parse import urlencode, urlsplit, urlunsplit

import numpy as np
from websockets.asyncio.client import connect as connect_async
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus
from websockets.sync.client import ClientConnection, connect

from tessera.client.errors import TesseraError
from tessera.wire.codec import CodecError, paste_into
from tessera.wire.protocol import ProtocolError, ViewerFrame, unpack_frame

#: Largest message the client's viewer socket takes: a raw frame of 8192×8192 and its table.
MAX_FRAME_BYTES = 8192 * 8192 * 3 + (1 << 20)


def view_socket_url(base_url: str, session_id: str | None, watch: bool = False) -> str:
    """``ws[s]://…/ws/view?session=ID`` under ``base_url`` (its path prefix kept)."""
    parts = urlsplit(base_url)
    scheme = {"http": "ws", "https": "wss"}.get(parts.scheme, parts.scheme)
    query = {} if session_id is None else {"session": session_id}
    if watch:
        query["watch"] = "1"
    return urlunsplit((scheme, parts.netloc, parts.path.rstrip("/") + "/ws/view", urlencode(query), ""))


def frame_image(frame: ViewerFrame) -> np.ndarray:
    """The frame's tiles decoded into one (h, w, 3) uint8 image."""
    width, height = frame.size
    image = np.zeros((height, width, 3), dtype=np.uint8)
    return paste_into(image, [(entry.rect, entry.codec, entry.node, payload) for entry, payload in frame.tiles])


def refused(exc: Exception, url: str) -> TesseraError:
    """The error of a viewer socket that did not open: the coordinator's answer, or why not."""
    if isinstance(exc, InvalidStatus):
        body = exc.response.body.decode(errors="replace").strip() if exc.response.body else ""
        return TesseraError(body or "the viewer socket was refused", exc.response.status_code, what="WS /ws/view")
    return TesseraError(f"cannot open the viewer socket at {url}: {exc}", what="WS /ws/view")


def closed(exc: ConnectionClosed) -> TesseraError:
    """The error of a viewer socket the coordinator closed, with its close code and reason."""
    received = exc.rcvd
    reason = received.reason if received is not None and received.reason else "the viewer socket closed"
    return TesseraError(reason, close_code=received.code if received else None, what="WS /ws/view")


class ViewSocket:
    """A viewer socket of the coordinator: its messages as they come (JSON as dicts, frames as
    bytes); every refusal or close is a :class:`TesseraError` with the coordinator's reason."""

    def __init__(self, base_url: str, session_id: str | None, token: str | None, timeout: float,
                 watch: bool = False) -> None:
        self.url = view_socket_url(base_url, session_id, watch)
        headers = {"Authorization": f"Bearer {token}"} if token else None
        try:
            opening = connect(self.url, additional_headers=headers, open_timeout=timeout, max_size=MAX_FRAME_BYTES,
                              compression=None)
            # Entered as a context manager: websockets 17.1 deprecated using connect()'s connection bare.
            self.connection: ClientConnection = opening.__enter__()
        except (OSError, InvalidHandshake, TimeoutError) as exc:
            raise refused(exc, self.url) from None

    def receive(self, timeout: float | None = None) -> dict[str, Any] | bytes:
        """The next message; TesseraError with the close reason once the coordinator closed it,
        TimeoutError after ``timeout`` s without one."""
        try:
            message = self.connection.recv(timeout)
        except ConnectionClosed as exc:
            raise closed(exc) from None
        if isinstance(message, str):
            return json.loads(message)
        return message

    def send(self, message: dict[str, Any]) -> None:
        try:
            self.connection.send(json.dumps(message))
        except ConnectionClosed:
            self.receive()   # raises with the reason
            raise

    def close(self) -> None:
        self.connection.close()

    def __enter__(self) -> ViewSocket:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def decode_frame(message: bytes) -> ViewerFrame:
    """A ``TFRM`` message parsed; TesseraError when it is not one."""
    try:
        return unpack_frame(message)
    except ProtocolError as exc:
        raise TesseraError(f"the coordinator sent a malformed frame: {exc}", what="WS /ws/view") from None


def composite(frame: ViewerFrame) -> np.ndarray:
    try:
        return frame_image(frame)
    except CodecError as exc:
        raise TesseraError(f"frame {frame.frame_id} does not decode: {exc}", what="WS /ws/view") from None


async def frames_async(base_url: str, session_id: str, token: str | None, timeout: float, still_only: bool = False,
                       frame_timeout: float | None = None) -> AsyncIterator[tuple[int, np.ndarray]]:
    """:meth:`tessera.client.Session.frames` for asyncio: the session's frames as (frame id, (h, w, 3)
    uint8 image), decoded off the event loop."""
    url = view_socket_url(base_url, session_id)
    headers = {"Authorization": f"Bearer {token}"} if token else None
    try:
        socket = await connect_async(url, additional_headers=headers, open_timeout=timeout, max_size=MAX_FRAME_BYTES,
                                     compression=None)
    except (OSError, InvalidHandshake, TimeoutError) as exc:
        raise refused(exc, url) from None
    try:
        while True:
            try:
                message = await asyncio.wait_for(socket.recv(), frame_timeout)
            except ConnectionClosed as exc:
                raise closed(exc) from None
            except TimeoutError:
                raise TesseraError(f"no frame in {frame_timeout} s", what="WS /ws/view") from None
            if isinstance(message, bytes):
                frame = decode_frame(message)
                if frame.still or not still_only:
                    yield frame.frame_id, await asyncio.to_thread(composite, frame)
    finally:
        await socket.close()
