"""The coordinator's socket guards as pure functions: the token bucket (clock passed in), a socket's
message limits, origin matching (same origin, behind a TLS proxy, the allow-list) and the flags."""

from __future__ import annotations

import pytest

from server.origins import OriginPolicy, format_origin, normalise_origins, own_origin, parse_origin
from server.routes.guards import SocketLimits, viewers_full
from server.settings import (
    DEFAULT_MAX_NODE_MESSAGES_PER_S,
    DEFAULT_MAX_VIEWER_MESSAGES_PER_S,
    Settings,
    auto_node_message_bytes,
    load_settings,
)
from tessera.wire.token_bucket import TokenBucket

# ------------------------------------------------------------------------------------- token bucket


def test_bucket_allows_its_burst_at_once_then_its_rate():
    bucket = TokenBucket(rate=10, burst=5, now=0.0)
    assert [bucket.take(0.0) for _ in range(6)] == [True] * 5 + [False]
    assert not bucket.take(0.05), "half a token after 50 ms"
    assert bucket.take(0.1) and not bucket.take(0.1)
    assert [bucket.take(10.0) for _ in range(6)] == [True] * 5 + [False], "never more than the burst"


def test_bucket_steady_rate_at_the_limit_passes_and_above_it_fails():
    at_rate = TokenBucket(rate=100, burst=100, now=0.0)
    assert all(at_rate.take(i / 100) for i in range(10_000))
    faster = TokenBucket(rate=100, burst=100, now=0.0)
    refused = [i for i in range(1000) if not faster.take(i / 150)]
    # 150/s against 100/s with 100 held: the bucket empties after 100 / (150 - 100) = 2 s (300 messages).
    assert refused and 290 <= refused[0] <= 310


def test_bucket_refusal_takes_nothing_and_a_clock_step_back_refills_nothing():
    bucket = TokenBucket(rate=1, burst=2, now=5.0)
    assert bucket.take(5.0, cost=2) and not bucket.take(5.0)
    assert not bucket.take(4.0), "a clock that steps back refills nothing"
    assert bucket.take(6.0)


@pytest.mark.parametrize("rate, burst", [(0, 1), (-1, 1), (float("nan"), 1), (float("inf"), 1), (1, 0.5),
                                         (1, float("inf"))])
def test_bucket_refuses_nonsense(rate, burst):
    with pytest.raises(ValueError):
        TokenBucket(rate, burst, 0.0)


# ------------------------------------------------------------------------------------ socket limits


def text(size: int) -> dict:
    return {"type": "websocket.receive", "text": "x" * size}


def test_socket_limits_size_counts_bytes_and_names_the_flag():
    limits = SocketLimits("viewer", max_bytes=100, rate=0, now=0.0)
    assert limits.refusal(text(100), 0.0) is None
    assert limits.refusal({"type": "websocket.receive", "bytes": b"x" * 100}, 0.0) is None
    code, reason = limits.refusal({"type": "websocket.receive", "bytes": b"x" * 101}, 0.0)
    assert code == 1009 and "101 bytes" in reason and "--max-viewer-message-bytes" in reason
    code, reason = limits.refusal({"type": "websocket.receive", "text": "é" * 60}, 0.0)  # 120 bytes of UTF-8
    assert code == 1009 and "120 bytes" in reason
    assert len(reason.encode()) <= 123, "fits a close frame"


def test_socket_limits_rate_names_the_flag():
    limits = SocketLimits("node", max_bytes=1000, rate=10, now=0.0)
    assert all(limits.refusal(text(1), 0.0) is None for _ in range(10))
    code, reason = limits.refusal(text(1), 0.0)
    assert code == 1008 and "10 messages/s" in reason and "--max-node-messages-per-s" in reason
    assert len(reason.encode()) <= 123


def test_default_rates_pass_legitimate_peers():
    """A viewer on a 240 Hz display (camera each refresh, latency each second) for a minute and a
    node doing 7,700 tiles/s (the coordinator's whole ceiling: a binary tile and a tile_sent each)
    for ten seconds pass."""
    viewer = SocketLimits("viewer", 64 << 10, DEFAULT_MAX_VIEWER_MESSAGES_PER_S, 0.0)
    sends = sorted([i / 240 for i in range(240 * 60)] + [float(second) for second in range(60)])
    assert all(viewer.refusal(text(200), now) is None for now in sends)
    node = SocketLimits("node", 1 << 20, DEFAULT_MAX_NODE_MESSAGES_PER_S, 0.0)
    assert all(node.refusal(text(200), i / (2 * 7700)) is None for i in range(2 * 7700 * 10))


def test_viewers_full():
    assert viewers_full(63, 64) is None
    assert "--max-viewers" in viewers_full(64, 64)
    assert viewers_full(10_000, 0) is None, "0: no limit"


# ------------------------------------------------------------------------------------------ origins


@pytest.mark.parametrize("header, origin", [
    ("http://localhost:8000", ("http", "localhost", 8000)),
    ("https://Example.COM", ("https", "example.com", 443)),
    ("http://example.com:80/", ("http", "example.com", 80)),
    ("http://[::1]:8000", ("http", "::1", 8000)),
    ("null", None), ("file://", None), ("ws://host:1", None), ("http://host/path", None),
    ("http://user@host", None), ("http://host:99999", None), ("http://host:x", None), ("", None),
    ("http://host?q=1", None),
])
def test_parse_origin(header, origin):
    assert parse_origin(header) == origin


def test_format_origin_round_trips():
    for text in ("http://localhost:8000", "https://example.com", "http://[::1]:8000", "https://h:8443"):
        assert format_origin(parse_origin(text)) == text


def test_own_origin_from_host_and_proxy_headers():
    assert own_origin("ws", "127.0.0.1:8000") == ("http", "127.0.0.1", 8000)
    assert own_origin("wss", "example.com") == ("https", "example.com", 443)
    # nginx in docker/proxy: Host forwarded as the browser sent it, X-Forwarded-Proto https.
    assert own_origin("ws", "localhost:8443", "https") == ("https", "localhost", 8443)
    assert own_origin("ws", "coordinator:8000", "https, http", "tessera.example") == ("https", "tessera.example", 443)
    assert own_origin("ws", None) is None
    assert own_origin("ws", "bad host/x") is None
    assert own_origin("ws", "h:1", "gopher") is None


def test_policy_same_origin_no_origin_allow_list_and_any():
    own = ("http", "127.0.0.1", 8000)
    policy = OriginPolicy()
    assert policy.refusal(None, own) is None, "no Origin: not a browser"
    assert policy.refusal("http://127.0.0.1:8000", own) is None
    for other in ("http://evil.example", "http://127.0.0.1:8001", "https://127.0.0.1:8000", "http://localhost:8000",
                  "null", "garbage"):
        reason = policy.refusal(other, own)
        assert reason and "--allowed-origins" in reason, other
    assert policy.refusal("http://127.0.0.1:8000", None) is not None, "no Host: nothing is same-origin"
    listed = OriginPolicy(["http://localhost:5173"])
    assert listed.refusal("http://localhost:5173", own) is None
    assert listed.refusal("http://localhost:5174", own) is not None
    assert OriginPolicy(["*"]).refusal("null", own) is None
    assert len(policy.refusal("http://" + "x" * 500, own).encode()) <= 123


def test_policy_behind_the_tls_proxy():
    """docker-compose.tls.yml: the browser opens https://HOST:8443; nginx forwards Host and sets
    X-Forwarded-Proto https. Without that header the page's https origin is not the coordinator's
    own: such a proxy needs --allowed-origins."""
    policy = OriginPolicy()
    assert policy.refusal("https://localhost:8443", own_origin("ws", "localhost:8443", "https")) is None
    assert policy.refusal("https://localhost:8443", own_origin("ws", "localhost:8443")) is not None
    assert policy.refusal("http://localhost:8443", own_origin("ws", "localhost:8443", "https")) is not None


# -------------------------------------------------------------------------------------------- flags


def test_flags_defaults_environment_and_validation():
    settings = load_settings([], {})
    assert (settings.allowed_origins, settings.max_viewers, settings.max_viewer_message_bytes) == ((), 64, 65536)
    assert (settings.max_viewer_messages_per_s, settings.max_node_messages_per_s) == (500.0, 40000.0)
    assert settings.node_message_bytes == auto_node_message_bytes((1280, 720)) == 12 * 1280 * 720 + (1 << 20)
    assert auto_node_message_bytes((8192, 8192)) > 8192 * 8192 * 7.5, "a colour + depth layer of the whole frame"
    settings = load_settings(["--allowed-origins", "https://A.example:443/, http://b.example:8080,*",
                              "--max-viewers", "0", "--max-viewer-message-bytes", "16K",
                              "--max-node-message-bytes", "256M", "--max-viewer-messages-per-s", "0"], {})
    assert settings.allowed_origins == ("https://a.example", "http://b.example:8080", "*")
    assert (settings.max_viewers, settings.max_viewer_message_bytes, settings.node_message_bytes,
            settings.max_viewer_messages_per_s) == (0, 16 << 10, 256 << 20, 0.0)
    settings = load_settings([], {"TESSERA_ALLOWED_ORIGINS": "http://x.example", "TESSERA_MAX_VIEWERS": "3",
                                  "TESSERA_MAX_NODE_MESSAGES_PER_S": "100"})
    assert (settings.allowed_origins, settings.max_viewers, settings.max_node_messages_per_s) == (
        ("http://x.example",), 3, 100.0)
    assert Settings(size=(16, 16)).node_message_bytes == 12 * 16 * 16 + (1 << 20)


@pytest.mark.parametrize("argv", [
    ["--allowed-origins", "example.com"], ["--allowed-origins", "http://h/path"], ["--max-viewers", "-1"],
    ["--max-viewer-message-bytes", "0"], ["--max-node-message-bytes", "lots"], ["--max-node-messages-per-s", "-5"],
    ["--max-viewer-messages-per-s", "inf"],
])
def test_bad_flags_exit_with_a_message(argv, capsys):
    with pytest.raises(SystemExit):
        load_settings(argv, {})
    assert "error" in capsys.readouterr().err


def test_normalise_origins():
    assert normalise_origins(" http://H:80 ,, https://h:8443/ ") == ("http://h", "https://h:8443")
    with pytest.raises(ValueError):
        normalise_origins("ftp://h")
