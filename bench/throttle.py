"""A slow link on loopback: a TCP proxy that passes what a server sends to its clients at a fixed
rate, for the tests and benchmarks of video to the browser (issue 21).

``throttled_proxy(port, bits_per_s)`` listens on a free loopback port and connects each client to
``port``: the client's bytes go up as they come, the server's come down at ``bits_per_s`` (paced on
a clock, so sleeping late is made up, in pieces of :data:`PIECE_BYTES`). The proxy reads the
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

#: Bytes passed down at once.
PIECE_BYTES = 4096
#: The receive buffer of the proxy's socket to the server (bytes).
SERVER_SIDE_BUFFER = 8192


def _pump(source: socket.socket, sink: socket.socket, bits_per_s: float | None, stop: threading.Event) -> None:
    """Copy ``source`` to ``sink`` until either ends, at ``bits_per_s`` (None: as fast as it comes)."""
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
    except OSError:
        pass
    finally:
        for end in (source, sink):
            with suppress(OSError):
                end.shutdown(socket.SHUT_RDWR)
            end.close()


@contextmanager
def throttled_proxy(port: int, bits_per_s: float) -> Iterator[int]:
    """A proxy to loopback ``port`` whose server → client direction carries ``bits_per_s``; yields
    the proxy's port."""
    listener = socket.create_server(("127.0.0.1", 0))
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
            for source, sink, rate in ((client, server, None), (server, client, bits_per_s)):
                thread = threading.Thread(target=_pump, args=(source, sink, rate, stop), daemon=True)
                thread.start()
                threads.append(thread)

    acceptor = threading.Thread(target=serve, daemon=True)
    acceptor.start()
    try:
        yield listener.getsockname()[1]
    finally:
        stop.set()
        acceptor.join(timeout=5)
        listener.close()
        for end in sockets:
            with suppress(OSError):
                end.shutdown(socket.SHUT_RDWR)
        for thread in threads:
            thread.join(timeout=5)
