"""The notebook view (issue 33): :class:`TesseraView`, an anywidget showing a session live.

Transport ``"comm"`` (the default): the kernel joins the session as a viewer (``WS /ws/view``)
and relays through the widget's comm — frames as the coordinator's binary TFRM messages, passed
on as comm buffers unchanged (never base64 in JSON), input and size from the page back to the
socket. Like jupyter_rfb, the page acknowledges each frame it takes; at most :data:`WINDOW`
frames are on their way unacknowledged, and meanwhile only the newest frame waits (older ones are
dropped), so a slow page or link gets fewer, fresher frames instead of a queue. The page needs
no route to the coordinator: JupyterHub, VS Code remote, Colab and SSH tunnels carry the comm.

Transport ``"direct"``: the page opens the coordinator's viewer socket itself (one hop less; the
page must reach the coordinator and be one of its ``--allowed-origins``).

The page's messages to the view's comm get no ``busy`` status from the kernel, only the ``idle``
(:mod:`tessera.client.kernel_status`): JupyterLab restyles the page at every status change.

While a cell runs, the kernel reads no comm message (the page's acknowledgements and input wait);
frames still go out, one per :data:`ACK_TIMEOUT_S` once the window is full.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import quote

import anywidget
import traitlets

from tessera.client.errors import TesseraError
from tessera.client.frames import ViewSocket, view_socket_url
from tessera.client.kernel_status import quiet, unquiet
from tessera.client.widget_bundle import widget_module

#: Frames sent through the comm and not yet acknowledged by the page, at most.
WINDOW = 2
#: After this long without an acknowledgement the page (or a kernel busy running a cell, which
#: reads no comm message) counts as having taken the frames in flight, s.
ACK_TIMEOUT_S = 1.0
#: How often the relay looks at the acknowledgement timeout while no message comes, s.
POLL_S = 0.25
TRANSPORTS = ("comm", "direct")
#: Hop times (page → kernel) kept for the median the frames carry back.
HOPS_KEPT = 60


class ViewedSession(Protocol):
    """What the view needs of a :class:`tessera.client.session.Session`."""

    id: str

    @property
    def connection(self) -> Any: ...


class CommRelay:
    """The kernel's side of the comm transport: a viewer socket of session ``session_id`` whose
    text messages go to ``control(message)`` and whose frames go to ``frame(bytes)`` at the pace
    the page acknowledges them; the page's input goes to the socket (:meth:`forward`)."""

    def __init__(self, open_socket: Callable[[], ViewSocket], control: Callable[[dict[str, Any]], None],
                 frame: Callable[[bytes, float], None]) -> None:
        self.open_socket = open_socket
        self.control = control
        self.frame = frame
        self.socket: ViewSocket | None = None
        self.lock = threading.Lock()
        self.in_flight = 0
        self.sent_at = 0.0
        self.waiting: bytes | None = None
        #: When the frame waiting came off the socket (monotonic s).
        self.waiting_since = 0.0
        self.latest: bytes | None = None
        #: The newest hello, with the camera and bounds updated since: what a page opened later needs.
        self.hello: dict[str, Any] | None = None
        self.closed = threading.Event()
        self.thread: threading.Thread | None = None
        self.frames_sent = 0
        self.frames_dropped = 0

    def start(self) -> None:
        """Connect (once) and relay on a thread of its own; a page that opens later gets the
        newest hello and frame again."""
        if self.thread is None:
            self.socket = self.open_socket()
            self.thread = threading.Thread(target=self._relay, name="tessera-view-relay", daemon=True)
            self.thread.start()
            return
        if self.hello is not None:
            self.control(self.hello)
        with self.lock:
            if self.waiting is None:
                self.waiting, self.waiting_since = self.latest, time.monotonic()
            self.in_flight = 0
            self._send_waiting(time.monotonic())

    def _relay(self) -> None:
        assert self.socket is not None
        while not self.closed.is_set():
            try:
                message = self.socket.receive(POLL_S)
            except TimeoutError:
                with self.lock:
                    self._send_waiting(time.monotonic())
                continue
            except TesseraError as exc:
                if not self.closed.is_set():
                    self.control({"type": "error", "message": exc.reason})
                return
            if isinstance(message, bytes):
                with self.lock:
                    if self.waiting is not None:
                        self.frames_dropped += 1
                    self.waiting = self.latest = message
                    self.waiting_since = time.monotonic()
                    self._send_waiting(self.waiting_since)
            else:
                self._remember(message)
                self.control(message)

    def _remember(self, message: dict[str, Any]) -> None:
        if message.get("type") == "hello":
            self.hello = dict(message)
        elif self.hello is not None and message.get("type") in ("camera", "scene"):
            self.hello.update({key: message[key] for key in ("camera", "bounds") if key in message})

    def _send_waiting(self, now: float) -> None:
        """Send the frame waiting if the window has room (or the page has been silent for
        :data:`ACK_TIMEOUT_S`). Called with the lock held."""
        if self.waiting is None:
            return
        if self.in_flight >= WINDOW and now - self.sent_at < ACK_TIMEOUT_S:
            return
        if self.in_flight >= WINDOW:
            self.in_flight = 0
        message, self.waiting = self.waiting, None
        self.in_flight += 1
        self.sent_at = now
        self.frames_sent += 1
        self.frame(message, now - self.waiting_since)

    def acknowledged(self) -> None:
        """The page took a frame: room for the newest one waiting."""
        with self.lock:
            self.in_flight = max(0, self.in_flight - 1)
            self._send_waiting(time.monotonic())

    def forward(self, message: dict[str, Any]) -> None:
        """A message of the page (camera, size, latency) to the coordinator."""
        if self.socket is not None and not self.closed.is_set():
            try:
                self.socket.send(message)
            except TesseraError as exc:
                self.control({"type": "error", "message": exc.reason})

    def stop(self) -> None:
        self.closed.set()
        if self.socket is not None:
            self.socket.close()
        if self.thread is not None and self.thread is not threading.current_thread():
            self.thread.join(timeout=5.0)


class TesseraView(anywidget.AnyWidget):
    """A live view of ``session`` in a notebook cell, ``width`` × ``height`` CSS px (frames of
    that size × devicePixelRatio): drag to orbit, right-drag or Shift-drag to pan, wheel or pinch
    to zoom, double-click to frame the scene; a badge says when the still is shown and a line
    gives the transport, size, frame, fps and input → frame latency. ``transport``: ``"comm"``
    (through the kernel) or ``"direct"`` (the page's own socket to the coordinator)."""

    _esm = widget_module()
    _css = Path(__file__).with_name("widget.css").read_text()
    width = traitlets.Int(640).tag(sync=True)
    height = traitlets.Int(360).tag(sync=True)
    transport = traitlets.Unicode("comm").tag(sync=True)
    direct_url = traitlets.Unicode("").tag(sync=True)

    def __init__(self, session: ViewedSession, width: int = 640, height: int = 360, transport: str = "comm") -> None:
        if transport not in TRANSPORTS:
            raise ValueError(f"transport is one of {TRANSPORTS}, got {transport!r}")
        connection = session.connection
        direct_url = ""
        if transport == "direct":
            direct_url = view_socket_url(connection.url, session.id)
            if connection.token:   # a browser sets no header on a WebSocket: the token goes in the query
                direct_url += f"&token={quote(connection.token, safe='')}"
        super().__init__(width=int(width), height=int(height), transport=transport, direct_url=direct_url)
        self.session = session
        self.relay: CommRelay | None = None
        #: How long the page's last messages took to reach the kernel (ms, this machine's clock).
        self.input_hops: deque[float] = deque(maxlen=HOPS_KEPT)
        if transport == "comm":
            self.relay = CommRelay(lambda: ViewSocket(connection.url, session.id, connection.token, connection.timeout),
                                   lambda message: self.send({"type": "control", "message": message}),
                                   self._send_frame)
            # One message a frame from the page: without a busy and an idle shown for each.
            quiet(self.comm.comm_id)
        self.on_msg(self._from_page)

    def _send_frame(self, frame: bytes, waited_s: float) -> None:
        """A frame to the page, stamped with this machine's clock (ms), how long it waited in the
        relay for the page's acknowledgements (ms), and the page's input's recent time to the kernel
        (the median, ms): what the comm itself costs, both ways."""
        hops = sorted(self.input_hops)
        self.send({"type": "frame", "sent_ms": time.time() * 1000.0, "waited_ms": waited_s * 1000.0,
                   "input_hop_ms": hops[len(hops) // 2] if hops else None}, buffers=[frame])

    def _from_page(self, _widget: Any, content: dict[str, Any], _buffers: list[Any]) -> None:
        if self.relay is None:
            return
        kind = content.get("type")
        if isinstance(content.get("sent_ms"), (int, float)):
            self.input_hops.append(time.time() * 1000.0 - content["sent_ms"])
        if kind == "ready":
            try:
                self.relay.start()
            except TesseraError as exc:   # the coordinator refused or is gone: the view's stats line says why
                self.send({"type": "control", "message": {"type": "error", "message": exc.reason}})
        elif kind == "ack":   # with the page's messages sent while it took the frame (the camera it held)
            for message in content.get("messages") or ():
                if isinstance(message, dict):
                    self.relay.forward(message)
            self.relay.acknowledged()
        elif kind == "viewer" and isinstance(content.get("message"), dict):
            self.relay.forward(content["message"])

    def close(self) -> None:
        """Stop relaying and close the widget (the session stays open)."""
        relay = getattr(self, "relay", None)   # None too for a view whose arguments were refused
        if relay is not None:
            relay.stop()
            comm = getattr(self, "comm", None)
            if comm is not None:
                unquiet(comm.comm_id)
        super().close()
