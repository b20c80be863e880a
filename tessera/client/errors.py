"""The client's one exception type: every HTTP or WebSocket error, with the coordinator's reason."""

from __future__ import annotations

from typing import Any

import httpx


class TesseraError(Exception):
    """A call the coordinator refused, or could not be made: ``reason`` is the coordinator's own
    words (FastAPI's ``detail``, a WebSocket close reason) or what went wrong on the way;
    ``status`` the HTTP status (None: no answer, or a WebSocket close: then ``close_code``)."""

    def __init__(self, reason: str, status: int | None = None, *, what: str = "",
                 close_code: int | None = None) -> None:
        self.reason = reason
        self.status = status
        self.what = what
        self.close_code = close_code
        code = f"HTTP {status}" if status is not None else (f"closed {close_code}" if close_code is not None else "")
        where = ", ".join(part for part in (code, what) if part)
        super().__init__(f"{reason} ({where})" if where else reason)


def detail_text(detail: Any) -> str:
    """FastAPI's ``detail``: a string as it is; a validation error's list as ``field: message; …``."""
    if isinstance(detail, str):
        return detail
    if isinstance(detail, list):
        parts = []
        for item in detail:
            if isinstance(item, dict):
                location = ".".join(str(p) for p in item.get("loc", [])[1:])
                parts.append(f"{location}: {item.get('msg', '')}" if location else str(item.get("msg", "")))
            else:
                parts.append(str(item))
        return "; ".join(parts)
    return str(detail)


def from_response(response: httpx.Response, what: str) -> TesseraError:
    """The error of a refused request, with the server's ``detail`` (or its text)."""
    try:
        body = response.json()
        reason = detail_text(body["detail"]) if isinstance(body, dict) and "detail" in body else response.text
    except ValueError:
        reason = response.text.strip() or response.reason_phrase
    return TesseraError(reason or response.reason_phrase, response.status_code, what=what)


def from_transport(exc: httpx.HTTPError, base_url: str, what: str) -> TesseraError:
    """The error of a request that got no answer: the coordinator unreachable, gone or too slow."""
    if isinstance(exc, httpx.TimeoutException):
        return TesseraError(f"no answer from the coordinator at {base_url} in time", what=what)
    if isinstance(exc, httpx.ConnectError):
        return TesseraError(f"cannot reach the coordinator at {base_url}: {exc}", what=what)
    return TesseraError(f"the coordinator at {base_url} went away: {exc}", what=what)
