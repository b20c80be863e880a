"""Which web pages may open the coordinator's WebSockets: the Origin check against cross-site
WebSocket hijacking. Pure functions of header values; the sockets' side is ``server/routes/guards.py``.

Browsers send ``Origin`` on every WebSocket handshake and a page cannot forge it, nor set
``X-Forwarded-Proto`` or ``X-Forwarded-Host`` on a WebSocket. So a page is let in when its origin
is the coordinator's own, as the browser addressed it (the ``Host`` header, or ``X-Forwarded-Host``
that a reverse proxy set, with the scheme from ``X-Forwarded-Proto`` when a TLS proxy set it), or
one of ``--allowed-origins``. A handshake without ``Origin`` comes from no browser (render nodes,
command-line tools): nothing to hijack, so it passes; tokens are what keeps those out.
"""

from __future__ import annotations

from collections.abc import Iterable
from urllib.parse import urlsplit

#: (scheme, host, port), as a browser compares origins: scheme ``http`` or ``https``, host lower case.
Origin = tuple[str, str, int]

ANY = "*"
DEFAULT_PORTS = {"http": 80, "https": 443}
#: The page scheme that goes with a socket's scheme.
PAGE_SCHEME = {"ws": "http", "wss": "https", "http": "http", "https": "https"}


def parse_origin(text: str) -> Origin | None:
    """``scheme://host[:port]`` (an ``Origin`` header, or an allow-list entry; a trailing ``/`` is
    accepted) as an Origin; None for anything else: ``null``, other schemes, paths, user names."""
    try:
        parts = urlsplit(text.strip())
        port = parts.port
    except ValueError:
        return None
    scheme = parts.scheme.lower()
    if (scheme not in DEFAULT_PORTS or not parts.hostname or parts.username is not None
            or parts.path not in ("", "/") or parts.query or parts.fragment):
        return None
    return scheme, parts.hostname.lower(), DEFAULT_PORTS[scheme] if port is None else port


def _first(header: str | None) -> str:
    """The first value of a header a chain of proxies may have appended to (``a, b``)."""
    return (header or "").split(",")[0].strip()


def own_origin(scheme: str, host: str | None, forwarded_proto: str | None = None,
               forwarded_host: str | None = None) -> Origin | None:
    """The origin of a page served by this coordinator, as the browser addressed it: ``host`` (the
    ``Host`` header) or ``forwarded_host``, with the socket's ``scheme`` or ``forwarded_proto``.
    None when the host is missing or malformed."""
    page_scheme = PAGE_SCHEME.get(_first(forwarded_proto).lower() or scheme.lower())
    address = _first(forwarded_host) or (host or "").strip()
    if page_scheme is None or not address:
        return None
    return parse_origin(f"{page_scheme}://{address}")


def format_origin(origin: Origin) -> str:
    scheme, host, port = origin
    shown = f"[{host}]" if ":" in host else host
    return f"{scheme}://{shown}" if port == DEFAULT_PORTS[scheme] else f"{scheme}://{shown}:{port}"


def parse_allowed(entry: str) -> Origin | str:
    """One ``--allowed-origins`` entry: an Origin, or ``*``; raises ValueError otherwise."""
    if entry.strip() == ANY:
        return ANY
    origin = parse_origin(entry)
    if origin is None:
        raise ValueError(f"{entry!r} is not an origin: scheme://host[:port] with http or https, or *")
    return origin


def normalise_origins(text: str) -> tuple[str, ...]:
    """``--allowed-origins`` (comma-separated) as canonical entries; raises ValueError on a bad one."""
    entries = (parse_allowed(entry) for entry in text.split(",") if entry.strip())
    return tuple(entry if isinstance(entry, str) else format_origin(entry) for entry in entries)


class OriginPolicy:
    """Same origin, plus the ``allowed`` origins (``*``: every page)."""

    def __init__(self, allowed: Iterable[str] = ()) -> None:
        entries = [parse_allowed(entry) for entry in allowed]
        self.any = ANY in entries
        self.allowed = frozenset(entry for entry in entries if not isinstance(entry, str))

    def refusal(self, origin: str | None, own: Origin | None) -> str | None:
        """Why a handshake with this ``Origin`` header is refused, or None when it may go on."""
        if origin is None or self.any:
            return None
        page = parse_origin(origin)
        if page is not None and (page == own or page in self.allowed):
            return None
        shown = origin if len(origin) <= 60 else origin[:59] + "…"
        return f"origin {shown!r} is not this coordinator's nor in --allowed-origins"


def path_prefix(text: str | None) -> str:
    """A path prefix (``--root-path``, ``X-Forwarded-Prefix``) as ``/a/b`` without a trailing slash
    (``""`` for none); anything that is no plain path (a scheme, ``//``, ``..``, a query, control
    characters) counts as none, so a link never points off this coordinator."""
    prefix = _first(text).rstrip("/")
    if not prefix:
        return ""
    if (not prefix.startswith("/") or prefix.startswith("//") or any(c in prefix for c in "?#\\\"'<> ")
            or any(ord(c) < 0x20 or ord(c) == 0x7F for c in prefix) or ".." in prefix.split("/")):
        return ""
    return prefix


def public_base(scheme: str, host: str | None, root_path: str = "", forwarded_proto: str | None = None,
                forwarded_host: str | None = None, forwarded_prefix: str | None = None) -> str:
    """The coordinator's address as the browser uses it, ending in ``/``: ``host`` (or a proxy's
    ``X-Forwarded-Host``) with ``scheme`` (or ``X-Forwarded-Proto``), under the proxy's
    ``X-Forwarded-Prefix`` or else ``--root-path``: the base of the links the coordinator returns."""
    origin = own_origin(scheme, host, forwarded_proto, forwarded_host)
    prefix = path_prefix(forwarded_prefix) or path_prefix(root_path)
    address = format_origin(origin) if origin is not None else f"{PAGE_SCHEME.get(scheme, 'http')}://localhost"
    return f"{address}{prefix}/"
