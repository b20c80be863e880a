"""Coordinator settings: defaults, TESSERA_* variables, command line over environment, validation."""

from __future__ import annotations

import pytest

from server.settings import DEFAULT_SCENE, Settings, load_settings, user_data_dir
from tessera.balancers import BALANCERS
from tessera.wire.codec import Codec


@pytest.fixture(autouse=True)
def _elsewhere(tmp_path, monkeypatch):
    """Start from a folder without scenes/: the defaults do not depend on where the tests run."""
    monkeypatch.chdir(tmp_path)


def plain_defaults(environ: dict[str, str]) -> Settings:
    """What a coordinator started without flags has: Settings()'s defaults and uploads in the user's data folder."""
    return Settings(user_data_dir=user_data_dir(environ))


def test_defaults():
    settings = load_settings([], {})
    assert settings == plain_defaults({})
    assert (settings.host, settings.port, settings.scene, settings.size) == ("127.0.0.1", 8000, DEFAULT_SCENE,
                                                                            (1280, 720))
    assert (settings.balancer, settings.token, settings.local_nodes, settings.codec) == ("adaptive-predict", None, 0,
                                                                                         Codec.JPEG)
    assert (settings.interactive_quality, settings.max_in_flight, settings.background, settings.node_slowdowns) == (
        60, 2, None, ())
    assert (settings.still_codec, settings.still_quality, settings.still_delay_ms, settings.settle_frames) == (
        Codec.PNG, 95, 200.0, 2)


def test_environment_variables_apply():
    settings = load_settings([], {
        "TESSERA_HOST": "0.0.0.0", "TESSERA_PORT": "9001", "TESSERA_SCENE": "builtin:grid",
        "TESSERA_SIZE": "640x480", "TESSERA_TOKEN": "s3cret", "TESSERA_LOCAL_NODES": "3",
        "TESSERA_CODEC": "png", "TESSERA_JPEG_QUALITY": "70", "TESSERA_MAX_IN_FLIGHT": "4", "TESSERA_MAX_FPS": "30",
        "TESSERA_BACKGROUND": "#ff0080", "TESSERA_NODE_SLOWDOWNS": "1,1,3", "TESSERA_LOG_LEVEL": "debug",
        "TESSERA_TILE_TIMEOUT_S": "5", "TESSERA_FRAME_WAIT_S": "2.5",
    })
    assert settings == Settings(
        host="0.0.0.0", port=9001, scene="builtin:grid", size=(640, 480), token="s3cret", local_nodes=3,
        codec=Codec.PNG, interactive_quality=70, max_in_flight=4, max_fps=30.0, background=(1.0, 0.0, 128 / 255),
        node_slowdowns=(1.0, 1.0, 3.0), log_level="debug", tile_timeout_s=5.0, frame_wait_s=2.5,
        user_data_dir=user_data_dir({}))


def test_quality_flags_old_and_new_names():
    assert load_settings(["--jpeg-quality", "70"], {}).interactive_quality == 70
    assert load_settings(["--interactive-quality", "55"], {"TESSERA_JPEG_QUALITY": "70"}).interactive_quality == 55
    assert load_settings([], {"TESSERA_INTERACTIVE_QUALITY": "40", "TESSERA_JPEG_QUALITY": "70"}) \
        .interactive_quality == 40
    settings = load_settings(["--still-codec", "jpeg", "--still-quality", "98", "--still-delay-ms", "150",
                              "--settle-frames", "0"], {})
    assert (settings.still_codec, settings.still_quality, settings.still_delay_ms, settings.settle_frames) == (
        Codec.JPEG, 98, 150.0, 0)
    assert load_settings(["--still-codec", "none"], {}).still_codec is None
    assert load_settings([], {"TESSERA_STILL_CODEC": "None"}).still_codec is None


def test_command_line_beats_environment():
    environ = {"TESSERA_SIZE": "640x480", "TESSERA_LOCAL_NODES": "3", "TESSERA_CODEC": "png"}
    settings = load_settings(["--size", "800x600", "--codec=raw"], environ)
    assert (settings.size, settings.codec, settings.local_nodes) == ((800, 600), Codec.RAW, 3)


def test_empty_and_unrelated_variables_are_ignored():
    environ = {"TESSERA_SIZE": "", "TESSERA_NOPE": "1", "SIZE": "16x16", "tessera_port": "1"}
    assert load_settings([], environ) == plain_defaults(environ)


def test_environ_argument_replaces_the_process_environment(monkeypatch):
    monkeypatch.setenv("TESSERA_PORT", "1234")
    assert load_settings([], {}).port == 8000
    assert load_settings([]).port == 1234


def test_a_token_that_starts_with_a_dash_is_still_a_token():
    assert load_settings([], {"TESSERA_TOKEN": "-Xq3v_Lk"}).token == "-Xq3v_Lk"
    assert load_settings(["--token=-Xq3v_Lk"], {}).token == "-Xq3v_Lk"


@pytest.mark.parametrize(("text", "slowdowns"), [("1", (1.0,)), ("1,1.5,3", (1.0, 1.5, 3.0)), (" 2 , 4", (2.0, 4.0))])
def test_node_slowdowns_parse(text, slowdowns):
    assert load_settings(["--node-slowdowns", text], {}).node_slowdowns == slowdowns


@pytest.mark.parametrize(("text", "background"), [
    ("#000000", (0.0, 0.0, 0.0)), ("#FFffFF", (1.0, 1.0, 1.0)), ("0.1,0.2,0.3", (0.1, 0.2, 0.3)),
    ("0,1,0", (0.0, 1.0, 0.0)),
])
def test_background_parses(text, background):
    assert load_settings(["--background", text], {}).background == pytest.approx(background)


@pytest.mark.parametrize(("text", "size"), [("1280x720", (1280, 720)), ("16X16", (16, 16)),
                                           ("8192x8192", (8192, 8192))])
def test_size_parses(text, size):
    assert load_settings(["--size", text], {}).size == size


@pytest.mark.parametrize("balancer", sorted(BALANCERS))
def test_every_registered_balancer_is_accepted(balancer):
    assert load_settings(["--balancer", balancer], {}).balancer == balancer


@pytest.mark.parametrize(("argv", "fragment"), [
    (["--size", "15x720"], "size"),
    (["--size", "1280x8193"], "size"),
    (["--size", "1280"], "size"),
    (["--size", "1280x720x3"], "size"),
    (["--size", "wide"], "size"),
    (["--size", "-640x480"], "size"),
    (["--background", "#12345"], "background"),
    (["--background", "#gggggg"], "background"),
    (["--background", "red"], "background"),
    (["--background", "1.5,0,0"], "background"),
    (["--background", "0.1,0.2"], "background"),
    (["--background", "nan,0,0"], "background"),
    (["--codec", "webp"], "codec"),
    (["--balancer", "nope"], "unknown balancer 'nope'; choose one of"),
    (["--jpeg-quality", "0"], "jpeg-quality"),
    (["--jpeg-quality", "101"], "jpeg-quality"),
    (["--jpeg-quality", "high"], "jpeg-quality"),
    (["--still-codec", "gif"], "still-codec"),
    (["--still-quality", "0"], "still-quality"),
    (["--still-delay-ms", "0"], "still-delay-ms"),
    (["--settle-frames", "-1"], "settle-frames"),
    (["--max-in-flight", "0"], "max-in-flight"),
    (["--max-fps", "0"], "max-fps"),
    (["--local-nodes", "-1"], "local-nodes"),
    (["--local-nodes", "two"], "local-nodes"),
    (["--port", "-1"], "port"),
    (["--node-slowdowns", "1,fast"], "node-slowdowns"),
    (["--node-slowdowns", "1,,2"], "node-slowdowns"),
    (["--node-slowdowns", "1,0.5"], "node-slowdowns"),
    (["--no-such-flag"], "unrecognized"),
])
def test_bad_values_exit_with_a_message(argv, fragment, capsys):
    with pytest.raises(SystemExit) as excinfo:
        load_settings(argv, {})
    assert excinfo.value.code == 2
    assert fragment in capsys.readouterr().err


@pytest.mark.parametrize(("variable", "value", "fragment"), [
    ("TESSERA_SIZE", "huge", "size"), ("TESSERA_CODEC", "gif", "codec"), ("TESSERA_BALANCER", "nope", "nope"),
    ("TESSERA_JPEG_QUALITY", "0", "jpeg-quality"), ("TESSERA_BACKGROUND", "blue", "background"),
])
def test_bad_environment_values_exit_with_a_message(variable, value, fragment, capsys):
    with pytest.raises(SystemExit) as excinfo:
        load_settings([], {variable: value})
    assert excinfo.value.code == 2
    assert fragment in capsys.readouterr().err


@pytest.mark.parametrize("argv", [
    ["--max-fps", "nan"],
    ["--node-slowdowns", "1,nan"],
    ["--node-slowdowns", "inf"],
    ["--tile-timeout-s", "0"],
    ["--tile-timeout-s", "-1"],
    ["--tile-timeout-s", "nan"],
    ["--frame-wait-s", "-1"],
    ["--frame-wait-s", "nan"],
    ["--port", "65536"],
], ids=lambda argv: " ".join(argv))
def test_out_of_range_numbers_are_refused_at_start_up(argv, capsys):
    with pytest.raises(SystemExit) as excinfo:
        load_settings(argv, {})
    assert excinfo.value.code == 2
    assert argv[0] in capsys.readouterr().err
