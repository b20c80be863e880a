"""``python -m server``'s listening socket."""

from __future__ import annotations

import socket

from server.__main__ import bind_socket


def test_the_listening_socket_hands_its_connections_tcp_nodelay():
    """Found by bench.hostile's request rate: uvicorn serving a socket handed in gets no TCP_NODELAY
    from asyncio, so Nagle's algorithm met the client's delayed ACK and every HTTP answer took about
    40 ms on loopback. Accepted connections inherit the option from the listening socket."""
    listener = bind_socket("127.0.0.1", 0)
    try:
        listener.listen()
        with socket.create_connection(listener.getsockname()):
            accepted, _ = listener.accept()
            with accepted:
                assert accepted.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)
    finally:
        listener.close()
