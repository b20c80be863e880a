"""One coordinator connection: its URL (a proxy's path prefix kept), token and HTTP client; each
request's error becomes a :class:`TesseraError` with the coordinator's reason."""

from __future__ import annotations

from typing import Any

import httpx

from tessera.client.errors import from_response, from_transport

#: Seconds a request may take, frame waits and uploads included.
DEFAULT_TIMEOUT_S = 120.0


class Connection:
    """The coordinator at ``url`` presenting ``token`` (None: none), requests timing out after
    ``timeout`` s."""

    def __init__(self, url: str, token: str | None = None, timeout: float = DEFAULT_TIMEOUT_S) -> None:
        self.url = url.rstrip("/") + "/"
        self.token = token
        self.timeout = timeout
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.http = httpx.Client(base_url=self.url, headers=headers, timeout=timeout)

    def request(self, method: str, path: str, **options: Any) -> httpx.Response:
        """``method`` ``path`` (relative to the coordinator's URL: ``api/…``) with httpx
        ``options``; the answer, or TesseraError with the coordinator's reason."""
        what = f"{method} /{path}"
        try:
            response = self.http.request(method, path, **options)
        except httpx.HTTPError as exc:
            raise from_transport(exc, self.url, what) from None
        if response.is_error:
            raise from_response(response, what)
        return response

    async def request_async(self, method: str, path: str, **options: Any) -> httpx.Response:
        """:meth:`request` for asyncio (a connection of its own for the call)."""
        what = f"{method} /{path}"
        try:
            async with httpx.AsyncClient(base_url=self.url, headers=self.http.headers, timeout=self.timeout) as client:
                response = await client.request(method, path, **options)
        except httpx.HTTPError as exc:
            raise from_transport(exc, self.url, what) from None
        if response.is_error:
            raise from_response(response, what)
        return response

    def call(self, method: str, path: str, **options: Any) -> Any:
        """:meth:`request`'s JSON answer (None for an empty one)."""
        response = self.request(method, path, **options)
        return response.json() if response.content else None

    def close(self) -> None:
        self.http.close()
