"""The coordinator under a path prefix behind a real reverse proxy (issue 33): Debian's nginx serves it
at ``/tessera/`` (prefix stripped, ``X-Forwarded-Prefix`` set). The viewer page opened from the link
the coordinator returns loads its scripts, sets its token cookie and opens its socket under the
prefix and draws frames; the Python client works through the same prefix."""

from __future__ import annotations

import httpx
import numpy as np
import pytest

from tessera.client import Tessera
from tests.browser_support import DRAWN_FRACTION_JS, chromium_context
from tests.conftest import seconds
from tests.proxy_support import nginx_prefix

pytestmark = [pytest.mark.browser, pytest.mark.integration, pytest.mark.gl]

TOKEN = "prefix-secret"


def test_the_viewer_and_the_client_work_under_a_prefix_behind_nginx(coordinator_factory, tmp_path):
    coordinator = coordinator_factory("--scene", "builtin:spheres", "--size", "160x120", "--local-nodes", "1",
                                      "--token", TOKEN)
    upstream = coordinator.url.split("//", 1)[1].rstrip("/")
    with nginx_prefix(upstream, "/tessera", tmp_path / "nginx", seconds(30)) as proxied, \
            Tessera(proxied, token=TOKEN, timeout=seconds(60)) as tessera:
        session = tessera.open_session("builtin:cluster", size=(120, 90))
        info = tessera.call("GET", f"api/sessions/{session.id}")
        assert info["viewer_url"] == f"{proxied}?session={session.id}", "the link carries the proxy's prefix"
        assert session.snapshot(still=False).shape == (90, 120, 3)
        frame_id, image = next(session.frames(timeout=seconds(60)))
        assert frame_id > 0 and image.std() > 2.0, "frames through the proxied viewer socket"
        direct = httpx.get(f"{coordinator.url}/", params={"token": TOKEN})
        assert "Path=/;" in direct.headers["set-cookie"], "without a proxy the cookie covers the coordinator's root"

        with chromium_context(tmp_path / "profile", viewport={"width": 640, "height": 480}) as context:
            page = context.new_page()
            errors: list[str] = []
            failed: list[str] = []
            page.on("pageerror", lambda error: errors.append(str(error)))
            page.on("requestfailed", lambda request: failed.append(request.url))
            outside: list[str] = []
            page.on("request", lambda request: outside.append(request.url)
                    if not request.url.startswith(proxied) and not request.url.startswith("data:") else None)
            page.goto(f"{info['viewer_url']}&token={TOKEN}")
            page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=seconds(60) * 1000, polling=100)
            cookies = {cookie["name"]: cookie for cookie in context.cookies()}
            assert cookies["tessera_token"]["path"] == "/tessera/", "the token cookie stays under the prefix"
            assert "token=" not in page.url
            assert page.evaluate("window.tessera.connected") is True
            assert session.info().viewers >= 1
            assert errors == [] and failed == [] and outside == [], (errors, failed, outside)
        session.close()
        assert np.isfinite(tessera.stats()["fps"])
