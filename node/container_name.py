"""A render node's default name inside a Docker container: its Compose service and replica.

Under Compose the only place a container can learn its own name (``tessera_node_2``; Compose v2:
``tessera-node-2``) is Docker's embedded DNS server (127.0.0.11, on every user-defined network): its
PTR record for the container's address is ``CONTAINER.NETWORK``, the network ``PROJECT_default``.
The C library's resolver cannot ask for it, because /etc/hosts, read first, maps that address to
the container id; so this module sends the one PTR query itself (RFC 1035 wire format, over UDP).
The name is the container's without ``PROJECT`` and its separator: ``node_2`` (v2: ``node-2``).

Swarm answers no PTR query for a replicated task's address; there docker-compose.yml's
``TESSERA_NAME`` template gives the name (node/settings.py).
"""

from __future__ import annotations

import secrets
import socket
import struct
from pathlib import Path

#: Docker's embedded DNS server, on every user-defined network.
DOCKER_DNS = ("127.0.0.11", 53)
#: The file Docker puts at the root of every container.
DOCKER_MARKER = Path("/.dockerenv")
#: Longest wait for the DNS answer, s.
TIMEOUT_S = 1.0
#: Compose's default network: ``PROJECT_default``.
DEFAULT_NETWORK_SUFFIX = "_default"
_PTR, _IN = 12, 1
_HEADER = struct.Struct(">HHHHHH")


def is_unexpanded_template(name: str) -> bool:
    """Whether ``name`` is a Swarm template nothing expanded (docker-compose.yml's ``TESSERA_NAME``,
    which Compose passes as written): the node then takes its default name."""
    return "{{" in name


def ptr_query(address: str, query_id: int) -> bytes:
    """A DNS query (recursion desired) for the PTR record of the IPv4 ``address``."""
    labels = [*reversed(address.split(".")), "in-addr", "arpa"]
    name = b"".join(bytes([len(label)]) + label.encode("ascii") for label in labels) + b"\0"
    return _HEADER.pack(query_id, 0x0100, 1, 0, 0, 0) + name + struct.pack(">HH", _PTR, _IN)


def _read_name(message: bytes, offset: int) -> tuple[str, int]:
    """The (possibly compressed) domain name at ``offset`` and the offset just after it; raises
    ValueError or IndexError for a malformed message."""
    labels: list[str] = []
    after = None
    for _ in range(128):  # a name has at most 127 labels; more means a loop of pointers
        length = message[offset]
        if length & 0xC0 == 0xC0:
            after = offset + 2 if after is None else after
            offset = ((length & 0x3F) << 8) | message[offset + 1]
            continue
        offset += 1
        if length == 0:
            return ".".join(labels), offset if after is None else after
        labels.append(message[offset:offset + length].decode("ascii"))
        offset += length
    raise ValueError("DNS name too long")


def ptr_answer(reply: bytes, query_id: int) -> str | None:
    """The first PTR name in the DNS ``reply`` to query ``query_id``; None for another query's
    reply, an error (NXDOMAIN included), no PTR record or a malformed message."""
    try:
        ident, flags, questions, answers, _, _ = _HEADER.unpack_from(reply)
        if ident != query_id or not flags & 0x8000 or flags & 0x000F:
            return None
        offset = _HEADER.size
        for _ in range(questions):
            offset = _read_name(reply, offset)[1] + 4
        for _ in range(answers):
            offset = _read_name(reply, offset)[1]
            kind, _, _, length = struct.unpack_from(">HHIH", reply, offset)
            offset += 10
            if kind == _PTR:
                return _read_name(reply, offset)[0]
            offset += length
    except (ValueError, IndexError, struct.error, UnicodeDecodeError):
        return None
    return None


def without_project(dns_name: str) -> str:
    """``CONTAINER.PROJECT_default`` → CONTAINER without ``PROJECT_`` or ``PROJECT-``; CONTAINER
    whole on another network or when it does not start with the project."""
    container, _, network = dns_name.partition(".")
    if network.endswith(DEFAULT_NETWORK_SUFFIX):
        project = network[:-len(DEFAULT_NETWORK_SUFFIX)]
        for separator in ("_", "-"):
            if project and container.startswith(project + separator) and len(container) > len(project) + 1:
                return container[len(project) + 1:]
    return container


def container_name(server: tuple[str, int] = DOCKER_DNS, timeout_s: float = TIMEOUT_S) -> str | None:
    """This container's Compose name without the project (``node_2``) as the DNS ``server`` names
    its address, or None where it does not (the default bridge network, Swarm, no container)."""
    try:
        address = socket.gethostbyname(socket.gethostname())
        query_id = secrets.randbits(16)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.settimeout(timeout_s)
            sock.connect(server)
            sock.send(ptr_query(address, query_id))
            reply = sock.recv(4096)
    except OSError:
        return None
    name = ptr_answer(reply, query_id)
    return without_project(name) if name else None
