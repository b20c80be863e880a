"""``python -m server``: run the coordinator (and ``--local-nodes N`` render nodes)."""

from __future__ import annotations

import asyncio
import logging
import socket
import sys

import uvicorn

from server.app import create_app
from server.local_nodes import LocalNodes
from server.scene_library import UPLOADS_FOLDER
from server.settings import Settings, load_settings

log = logging.getLogger("tessera.server")
#: Connections the listening socket queues before the server accepts them (uvicorn's default).
LISTEN_BACKLOG = 2048


def bind_socket(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    # Accepted connections inherit it. asyncio sets it on the transports of servers it opens, not
    # on those of a socket handed in: without it Nagle's algorithm met the client's delayed ACK
    # and every HTTP answer took about 40 ms on loopback (found by bench.hostile's request rate).
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.bind((host, port))
    sock.set_inheritable(True)
    return sock


async def serve(settings: Settings) -> None:
    sock = bind_socket(settings.host, settings.port)
    port = sock.getsockname()[1]
    nodes = LocalNodes()
    try:
        if settings.local_nodes:   # they start (imports, GL) while this process does; the socket queues
            sock.listen(LISTEN_BACKLOG)   # their connections until the server accepts them
            nodes.spawn(settings.local_nodes, f"ws://127.0.0.1:{port}/ws/node", settings.token,
                        settings.node_slowdowns)
        await _serve(settings, sock, port)
    finally:
        nodes.stop()


async def _serve(settings: Settings, sock: socket.socket, port: int) -> None:
    # The socket layer's own cap is the largest message any socket may send; /ws/view's lower limit
    # is checked per message (server/routes/guards.py).
    max_message = max(settings.node_message_bytes, settings.max_viewer_message_bytes)
    config = uvicorn.Config(create_app(settings), log_level=settings.log_level, ws_max_size=max_message,
                            ws_ping_interval=settings.heartbeat_s, ws_ping_timeout=2 * settings.heartbeat_s,
                            access_log=False, lifespan="on", root_path=settings.root_path)
    server = uvicorn.Server(config)
    task = asyncio.create_task(server.serve(sockets=[sock]))
    while not server.started:
        if task.done():
            await task
            return
        await asyncio.sleep(0.05)
    shown_host = "localhost" if settings.host in ("0.0.0.0", "::") else settings.host
    print(f"Tessera serving on http://{shown_host}:{port}/", flush=True)
    for line in where_scenes_are(settings):
        print(line, flush=True)
    await task


def where_scenes_are(settings: Settings) -> list[str]:
    """What the start-up tells of the scene library and the uploads: their folders, or how to get them."""
    library = (f"  scene library: {settings.scenes_dir}" if settings.scenes_dir is not None else
               "  scene library: none (--scenes-dir DIR, or start from a folder that holds scenes/)")
    home = settings.uploads_home
    if home is None:
        uploads = "  uploads: off (--data-dir DIR turns them on)"
    elif settings.data_dir is None:
        uploads = f"  uploads: {home / UPLOADS_FOLDER} (sessions are kept across restarts only with --data-dir DIR)"
    else:
        uploads = f"  uploads and sessions: {home}"
    return [library, uploads]


def main(argv: list[str] | None = None) -> int:
    settings = load_settings(argv)
    logging.basicConfig(level=settings.log_level.upper(), format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        asyncio.run(serve(settings))
    except KeyboardInterrupt:
        pass
    except OSError as exc:
        print(f"tessera: cannot serve on {settings.host}:{settings.port}: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
