"""A link on loopback: a TCP proxy that passes what a server sends to its clients, at a fixed rate
if asked, and counts it — for the tests and benchmarks of video to the browser (issue 21).

``throttled_proxy(port, bits_per_s)`` listens on a free loopback port and connects each client to
``port``: the client's bytes go up as they come, the server's come down at ``bits_per_s`` (None: as
they come; paced on a clock, so sleeping late is made up, in pieces of :data:`PIECE_BYTES`), each
piece noted with its time (:class:`Link`): the bytes on the wire, after the WebSocket's own
compression (permessage-deflate, which a browser and the coordinator agree on). The proxy reads the
server's side into a small receive buffer (:data:`SERVER_SIDE_BUFFER`), so a server that sends
faster than the link fills its own socket's buffers, as behind a real bottleneck. Threads, one pair
per connection; every connection is shut when the context ends.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field

#: Bytes passed down at once.
PIECE_BYTES = 4096
#: The receive buffer of the proxy's socket to the server (bytes).
SERVER_SIDE_BUFFER = 8192


@dataclass
class Link:
    """The proxy's ``port`` and the pieces it passed down: (perf_counter s when sent, bytes)."""

    port: int
    pieces: list[tuple[float, int]] = field(default_factory=list)

    def bytes_between(self, start: float, end: float) -> int:
        """Bytes passed down from ``start`` to ``end`` (perf_counter s)."""
        return sum(size for at, size in list(self.pieces) if start <= at <= end)


def _pump(source: socket.socket, sink: socket.socket, bits_per_s: float | None, stop: threading.Event,
          pieces: list[tuple[float, int]] | None) -> None:
    """Copy ``source`` to ``sink`` until either ends, at ``bits_per_s`` (None: as fast as it comes),
    noting each piece in ``pieces`` (None: not noted)."""
    due = time.perf_counter()
    try:
        while not stop.is_set():
            data = source.recv(PIECE_BYTES)
            if not data:
                break
            if bits_per_s:
                due = max(due, time.perf_counter() - 0.05)   # an idle link saves up at most 50 ms
                time.sleep(max(0.0, due - time.perf_counter()))
                due += len(data) * 8.0 / bits_per_s
            sink.sendall(data)
            if pieces is not None:
                pieces.append((time.perf_counter(), len(data)))
    except OSError:
        pass
    finally:
        for end in (source, sink):
            with suppress(OSError):
                end.shutdown(socket.SHUT_RDWR)
            end.close()


@contextmanager
def throttled_proxy(port: int, bits_per_s: float | None) -> Iterator[Link]:
    """A proxy to loopback ``port`` whose server → client direction carries ``bits_per_s`` (None:
    what comes); yields its :class:`Link` (every connection's pieces down, together)."""
    listener = socket.create_server(("127.0.0.1", 0))
    link = Link(listener.getsockname()[1])
    listener.settimeout(0.2)
    stop = threading.Event()
    threads: list[threading.Thread] = []
    sockets: list[socket.socket] = []

    def serve() -> None:
        while not stop.is_set():
            try:
                client, _ = listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            server = socket.socket()
            server.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, SERVER_SIDE_BUFFER)
            server.connect(("127.0.0.1", port))
            sockets.extend((client, server))
            for source, sink, rate, pieces in ((client, server, None, None), (server, client, bits_per_s, link.pieces)):
                thread = threading.Thread(target=_pump, args=(source, sink, rate, stop, pieces), daemon=True)
                thread.start()
                threads.append(thread)

    acceptor = threading.Thread(target=serve, daemon=True)
    acceptor.start()
    try:
        yield link
    finally:
        stop.set()
        acceptor.join(timeout=5)
        listener.close()
        for end in sockets:
            with suppress(OSError):
                end.shutdown(socket.SHUT_RDWR)
        for thread in threads:
            thread.join(timeout=5)
