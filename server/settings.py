"""The coordinator's one typed settings object, from the command line and ``TESSERA_<FLAG>``
environment variables (a flag on the command line wins), validated at start-up."""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from server.origins import normalise_origins, path_prefix
from tessera.cli_values import (
    command_name,
    number_parser,
    parse_background,
    parse_point_budget,
    parse_samples_max,
    parse_still_samples,
    parse_target_db,
    size_parser,
)
from tessera.decomposition.chunk_ownership import DEFAULT_DEPTH_STRIP
from tessera.decomposition.modes import MODES
from tessera.scheduling.refinement import DEFAULT_STILL_SAMPLES
from tessera.scheduling.render_jobs import MAX_POSTER_SIDE
from tessera.scheduling.scheduler import SchedulerConfig
from tessera.video.link_rate import MIN_BITRATE
from tessera.video.transport import STREAM_MODES
from tessera.wire.codec import Codec
from tessera.wire.messages import MAX_LOD_ERROR_PX, MAX_POINT_SIZE

DEFAULT_SCENE = "builtin:cluster"
#: The best measured balancer (docs/benchmarks/balance.md: bench.balance on Lucy's orbit, fly-through and orbit
#: with speeds 1,1,2,4 and the Pan's orbit, and bench.live): the highest speedup on two of the four,
#: within 2–3 % of the best on the others, the lowest or second-lowest imbalance on all four.
DEFAULT_BALANCER = "adaptive-predict"
parse_size = size_parser(16, 8192)
parse_poster_size = size_parser(16, MAX_POSTER_SIDE)
#: Most viewer sockets at once: every viewer gets every frame, about 23 KB at 720p × 60 frames/s
#: = 1.4 MB/s, so 64 of them fill a gigabit link; a slow viewer only skips frames.
DEFAULT_MAX_VIEWERS = 64
#: --max-bitrate: Selkies' default, and what 1080p at 60 fps needs at BITS_PER_PIXEL (6.2 Mbit/s).
DEFAULT_MAX_BITRATE = 8_000_000
#: Largest message a viewer may send: it sends camera and latency JSON of a few hundred bytes.
DEFAULT_MAX_VIEWER_MESSAGE_BYTES = 64 << 10
#: Messages per second a viewer may send (burst: one second's worth): it sends the camera at most
#: once per display refresh (60–240 Hz) and its latency once a second.
DEFAULT_MAX_VIEWER_MESSAGES_PER_S = 500.0
#: Messages per second a node may send (burst: one second's worth): two per tile (the binary tile and
#: its ``tile_sent``). Receiving a tile costs the coordinator 0.13–0.15 ms (bench.scale over loopback), so
#: it takes at most about 7,700 tiles/s (15,400 messages/s) from all nodes together, whatever the tiles
#: per frame (768 tiles at 60 frames/s would be 46,000): no node doing its work comes near 40,000.
DEFAULT_MAX_NODE_MESSAGES_PER_S = 40000.0


#: Bytes per pixel of the largest tile encoding, with room: raw RGB is 3, PNG of noise 3.003, JPEG of noise
#: at quality 100 4.1, and a colour + depth layer in the active-pixel encoding (tessera/wire/active_pixels.py)
#: 7 when every pixel is active, 7.5 when every other one is.
MAX_TILE_BYTES_PER_PIXEL = 12


#: Messages per second, 0 for no limit.
RATE = number_parser(0.0, note=" (0: no limit)")
POSITIVE = number_parser(0.0, above=True)
LOD_PIXELS = number_parser(0.0, note=" of pixels", maximum=MAX_LOD_ERROR_PX)


def auto_node_message_bytes(size: tuple[int, int]) -> int:
    """Largest message a node may send by default: a tile is at most the whole frame, at most
    :data:`MAX_TILE_BYTES_PER_PIXEL` (four raw RGB frames), plus 1 MiB for the tile header and the
    largest JSON (``tessera.wire.messages.MAX_JSON_BYTES``): 12.1 MB at 1280x720, 806 MB at 8192x8192."""
    return MAX_TILE_BYTES_PER_PIXEL * size[0] * size[1] + (1 << 20)


_BYTE_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30}


def _byte_count(text: str) -> int:
    """Bytes, optionally with K, M or G (powers of 1024): ``65536``, ``64K``, ``256M``; at least 1."""
    cleaned = text.strip().upper().removesuffix("B").removesuffix("I")
    unit = cleaned[-1:] if cleaned[-1:] in _BYTE_UNITS else ""
    value = _count(cleaned[:len(cleaned) - len(unit)]) * _BYTE_UNITS[unit]
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1 byte, got {text!r}")
    return value


def _bitrate(text: str) -> int:
    """Bits per second, optionally with k or M (powers of 1000): ``8000000``, ``2500k``, ``8M``."""
    cleaned = text.strip().lower().removesuffix("bit/s").removesuffix("bps")
    unit = cleaned[-1:] if cleaned[-1:] in ("k", "m") else ""
    try:
        value = float(cleaned[:len(cleaned) - len(unit)]) * {"": 1, "k": 1e3, "m": 1e6}[unit]
    except ValueError:
        raise argparse.ArgumentTypeError(f"a bitrate is bits per second, e.g. 8M or 2500k, got {text!r}") from None
    if not math.isfinite(value) or value < MIN_BITRATE:
        raise argparse.ArgumentTypeError(f"a bitrate must be at least {MIN_BITRATE} bit/s, got {text!r}")
    return int(value)


def _origins(text: str) -> tuple[str, ...]:
    try:
        return normalise_origins(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _count(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def _port(text: str) -> int:
    value = _count(text)
    if value > 65535:
        raise argparse.ArgumentTypeError(f"ports are 0…65535, got {value}")
    return value


def _folder(text: str) -> Path:
    path = Path(text).expanduser()
    if not path.is_dir():
        raise argparse.ArgumentTypeError(f"must be an existing folder, got {text!r}")
    return path


def _root_path(text: str) -> str:
    prefix = path_prefix(text)
    if text.strip().rstrip("/") and not prefix:
        raise argparse.ArgumentTypeError(f"a root path is a plain path such as /tessera, got {text!r}")
    return prefix


#: ``--data-dir none``: no uploads, nothing kept.
NO_DATA_DIR = "none"


def _data_folder(text: str) -> Path | str:
    """An existing folder, or ``none``."""
    return NO_DATA_DIR if text.strip().lower() == NO_DATA_DIR else _folder(text)


def user_data_dir(environ: dict[str, str]) -> Path:
    """Tessera's folder in the user's data directory: ``$XDG_DATA_HOME/tessera`` (default
    ``~/.local/share/tessera``)."""
    base = environ.get("XDG_DATA_HOME") or str(Path(environ.get("HOME") or Path.home()) / ".local" / "share")
    return Path(base).expanduser() / "tessera"


#: The scene library a coordinator started without ``--scenes-dir`` shows, when its working folder has it.
SCENES_FOLDER = Path("scenes")


def _megabytes(text: str) -> int:
    value = _count(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _codec(text: str) -> Codec:
    try:
        return Codec.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


NO_STILL = "none"


def _still_codec(text: str) -> Codec | str:
    """A codec for the still frame, or ``none`` (kept as the string: None means "not given")."""
    return NO_STILL if text.strip().lower() == NO_STILL else _codec(text)


def _quality(text: str) -> int:
    value = _count(text)
    if not 1 <= value <= 100:
        raise argparse.ArgumentTypeError(f"JPEG quality is 1…100, got {value}")
    return value


@dataclass(frozen=True)
class Settings(SchedulerConfig):
    """Every setting of the coordinator: the frame scheduler's (:class:`SchedulerConfig`, its
    fields and defaults: ``size``, the codecs and qualities, ``still_delay_ms``, ``settle_frames``,
    ``max_in_flight``, ``max_fps``, ``tile_timeout_s``, ``mode``, ``depth_strip``, ``background``,
    …; :meth:`scheduler_config` hands them on) and the service's own below."""

    #: The coordinator's still accumulates samples until it converges (the scheduler alone renders
    #: one still frame).
    still_samples: int = DEFAULT_STILL_SAMPLES
    host: str = "127.0.0.1"
    port: int = 8000
    scene: str = DEFAULT_SCENE
    balancer: str = DEFAULT_BALANCER
    token: str | None = None
    local_nodes: int = 0
    #: WebSocket ping interval to every node and viewer (s); a peer that has not answered a ping
    #: within twice as long is disconnected (a frozen node that owes no tile, a dead network).
    heartbeat_s: float = 10.0
    frame_wait_s: float = 30.0
    node_slowdowns: tuple[float, ...] = ()
    log_level: str = "info"
    #: Pages of other origins whose viewers may open the sockets (``*``: any page); same origin always may.
    allowed_origins: tuple[str, ...] = ()
    max_viewers: int = DEFAULT_MAX_VIEWERS
    max_viewer_message_bytes: int = DEFAULT_MAX_VIEWER_MESSAGE_BYTES
    #: None: :func:`auto_node_message_bytes` of ``size``.
    max_node_message_bytes: int | None = None
    max_viewer_messages_per_s: float = DEFAULT_MAX_VIEWER_MESSAGES_PER_S
    max_node_messages_per_s: float = DEFAULT_MAX_NODE_MESSAGES_PER_S
    #: The scene library, read only: its files are listed as ``library/PATH`` (server/scene_library.py).
    scenes_dir: Path | None = None
    #: ``--data-dir``: where uploads (``DIR/scenes``) and the sessions (``DIR/sessions.json``, brought
    #: back at start-up) live.
    data_dir: Path | None = None
    #: Without ``--data-dir``: where uploads live (the user's data folder, ``XDG_DATA_HOME/tessera``);
    #: sessions are not kept. Both None: uploads are refused.
    user_data_dir: Path | None = None
    max_upload_mb: int = 512
    #: Address space of the process that loads an upload to check it (server/upload_check.py), MiB.
    upload_check_memory_mb: int = 4096
    #: Sessions open at once, the default one included; more are refused with 503.
    max_sessions: int = 16
    #: A session (not the default one) with no viewer and no API call for this long is closed (s).
    session_idle_timeout_s: float = 300.0
    #: The largest frame a session may have (a bigger request is scaled down to fit, aspect kept).
    max_size: tuple[int, int] = (3840, 2160)
    #: Render jobs (issue 35): unfinished at once, a poster's largest size, a film's most frames.
    max_jobs: int = 4
    max_poster_size: tuple[int, int] = (MAX_POSTER_SIDE, MAX_POSTER_SIDE)
    max_film_frames: int = 18000
    #: What viewers get while the picture changes (issue 21): ``auto`` (video in the first codec
    #: the viewer decodes, else tiles), ``h264``, ``vp9`` or ``tiles`` (:data:`STREAM_MODES`).
    stream: str = "auto"
    #: The highest bitrate of a session's video stream, bit/s.
    max_bitrate: int = DEFAULT_MAX_BITRATE
    #: The path prefix a reverse proxy serves the coordinator under (``/tessera``; "" for none),
    #: for the links it returns when the proxy sends no ``X-Forwarded-Prefix``.
    root_path: str = ""

    @property
    def uploads_home(self) -> Path | None:
        """The folder whose ``scenes`` sub-folder holds the uploads (None: uploads are off)."""
        return self.data_dir or self.user_data_dir

    @property
    def node_message_bytes(self) -> int:
        """The largest message a node may send, given or from the frame size."""
        return self.max_node_message_bytes or auto_node_message_bytes(self.size)


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    """The coordinator's parser; ``prog`` names the command in its usage (default: as invoked)."""
    defaults = Settings()
    parser = argparse.ArgumentParser(
        prog=prog or command_name(sys.argv[0], "server"),
        description="Tessera coordinator: partitions the screen, gathers tiles from render nodes, "
        "serves the viewer. Every flag can also be set as TESSERA_<FLAG> (e.g. TESSERA_SCENE, TESSERA_LOCAL_NODES).",
    )
    parser.add_argument("--host", help=f"address to listen on (default {defaults.host}: this machine only; "
                                       "0.0.0.0 for every network)")
    parser.add_argument("--port", type=_port, help=f"port (default {defaults.port}; 0 picks a free one)")
    parser.add_argument("--scene", metavar="FILE|builtin:NAME",
                        help="what the shared default session shows: a scene file (glTF/GLB/OBJ/PLY/STL) or "
                             f"builtin:NAME (default {DEFAULT_SCENE})")
    parser.add_argument("--size", type=parse_size, metavar="WxH",
                        help=f"frame size of the default session (default {defaults.size[0]}x{defaults.size[1]}; "
                             "other sessions follow their viewer's window)")
    parser.add_argument("--balancer", metavar="NAME",
                        help=f"how the screen is split between the nodes (default {DEFAULT_BALANCER}; "
                             "GET /api/balancer lists them, and the viewer's panel switches them live)")
    parser.add_argument("--mode", choices=MODES,
                        help="how the nodes share the work: sort-first (default: each node draws its own part of "
                             "the screen and holds the whole scene), hybrid (each part of the scene is drawn once, "
                             "by one node, and the edges are merged by depth) or sort-last (each node holds only "
                             "a share of the scene; their pictures are merged by depth)")
    parser.add_argument("--depth-strip", type=_count, metavar="PX",
                        help=f"with --mode hybrid: width of the edge strips merged by depth, px "
                             f"(default {DEFAULT_DEPTH_STRIP})")
    parser.add_argument("--token", metavar="SECRET",
                        help="shared secret that nodes, viewers and API calls must present (default: none; set one "
                             "on any network you share)")
    parser.add_argument("--local-nodes", type=_count, metavar="N",
                        help="start N render nodes on this machine with the coordinator (default 0: nodes join "
                             "from elsewhere with tessera-node --coordinator ws://HOST:PORT/ws/node)")
    parser.add_argument("--codec", type=_codec,
                        help="tile codec while the picture changes: jpeg (default), png (lossless) or raw")
    parser.add_argument("--interactive-quality", "--jpeg-quality", dest="interactive_quality", type=_quality,
                        help=f"JPEG quality 1…100 of interactive frames (default {defaults.interactive_quality}; "
                             "--jpeg-quality is the old name)")
    parser.add_argument("--still-codec", type=_still_codec,
                        help="codec of the still frame rendered once nothing changed for --still-delay-ms: "
                             "png (default, lossless), raw, jpeg, or none for no still frame")
    parser.add_argument("--still-quality", type=_quality,
                        help=f"JPEG quality of a jpeg still frame (default {defaults.still_quality})")
    parser.add_argument("--still-delay-ms", type=POSITIVE,
                        help=f"quiet time before the still frame, ms (default {defaults.still_delay_ms:g})")
    parser.add_argument("--still-samples", type=parse_still_samples,
                        help="jittered frames the still accumulates once nothing changed (the progressive still): "
                             "auto (default) until its estimated PSNR against the converged image reaches "
                             "--still-target-db, or a fixed count (1: one frame, not shifted; at most 127)")
    parser.add_argument("--still-samples-max", type=parse_samples_max,
                        help=f"most samples of an adaptive still (default {defaults.still_samples_max})")
    parser.add_argument("--still-target-db", type=parse_target_db,
                        help="an adaptive still stops once its estimated PSNR against the image it converges to "
                             f"reaches this, dB (default {defaults.still_target_db:g})")
    parser.add_argument("--settle-frames", type=_count,
                        help="at most this many frames more after a change while the balancer's partition "
                             f"still moves (default {defaults.settle_frames})")
    parser.add_argument("--max-in-flight", type=int,
                        help=f"frames rendering at once (default {defaults.max_in_flight})")
    parser.add_argument("--max-fps", type=POSITIVE, help=f"frame rate cap (default {defaults.max_fps:g})")
    parser.add_argument("--lod-error-px", type=LOD_PIXELS, metavar="PX",
                        help="levels of detail: a moving frame draws each part of a big model at the coarsest "
                             "level whose error on screen is at most this many pixels, and the still after it at "
                             f"full detail (default {defaults.lod_error_px:g}; 0: always full detail)")
    parser.add_argument("--lod-max-error-px", type=LOD_PIXELS, metavar="PX",
                        help="the most that bound is raised to while frames are slower than --target-fps "
                             f"(default {defaults.lod_max_error_px:g})")
    parser.add_argument("--target-fps", type=POSITIVE,
                        help="the moving frame rate levels of detail and the point budget aim at: the bound rises (the "
                             "budget falls) while frames take longer and falls back when they are quick "
                             f"(default {defaults.target_fps:g})")
    parser.add_argument("--point-budget", type=parse_point_budget, metavar="N",
                        help="point clouds: a moving frame draws at most this many points, the octree's nodes "
                             "nearest and largest on screen first, a budget that starts here and follows "
                             "--target-fps between --point-budget-min and --point-budget-max; the still after it "
                             f"draws every point in view (default {defaults.point_budget})")
    parser.add_argument("--point-budget-min", type=parse_point_budget, metavar="N",
                        help="the fewest points the budget is lowered to while moving frames are slower than "
                             f"--target-fps (default {defaults.point_budget_min}, or --point-budget where fewer)")
    parser.add_argument("--point-budget-max", type=parse_point_budget, metavar="N",
                        help="the most points the budget is raised to while moving frames are quicker than "
                             f"--target-fps (default {defaults.point_budget_max}; set both bounds to --point-budget "
                             "for a fixed budget)")
    parser.add_argument("--point-size", type=number_parser(0.0, above=True, maximum=MAX_POINT_SIZE, note=" px"),
                        metavar="PX", help="point clouds: each point is a square at least this many pixels wide, "
                                           f"wider where its level's spacing is (default {defaults.point_size:g})")
    parser.add_argument("--tile-timeout-s", type=POSITIVE,
                        help="seconds before a node that owes a tile is dropped "
                             f"(default {defaults.tile_timeout_s:g})")
    parser.add_argument("--heartbeat-s", type=POSITIVE,
                        help="seconds between WebSocket pings to nodes and viewers; a peer that has not answered "
                             f"one within twice as long is disconnected (default {defaults.heartbeat_s:g})")
    parser.add_argument("--frame-wait-s", type=POSITIVE,
                        help=f"longest wait of GET /api/frame.png (default {defaults.frame_wait_s:g})")
    parser.add_argument("--background", type=parse_background, help="clear colour '#rrggbb' or 'r,g,b'")
    parser.add_argument("--node-slowdowns", help="with --local-nodes: comma-separated --slowdown per node, e.g. 1,1,3")
    parser.add_argument("--log-level", help="debug, info (default), warning")
    parser.add_argument("--allowed-origins", type=_origins,
                        help="comma-separated origins (scheme://host[:port]) of other sites whose pages may open "
                             "the viewer and node sockets, or * for any; the coordinator's own origin always may")
    parser.add_argument("--max-viewers", type=_count,
                        help=f"viewer sockets at once (default {DEFAULT_MAX_VIEWERS}; 0: no limit)")
    parser.add_argument("--max-viewer-message-bytes", type=_byte_count,
                        help="largest message a viewer may send, bytes, K/M/G allowed (default 64K)")
    parser.add_argument("--max-node-message-bytes", type=_byte_count,
                        help="largest message (a tile) a node may send (default: 12 bytes per pixel of --size "
                             "plus 1M, 12.1 MB at 1280x720)")
    parser.add_argument("--max-viewer-messages-per-s", type=RATE,
                        help=f"messages per second per viewer socket, a second's worth at once "
                             f"(default {DEFAULT_MAX_VIEWER_MESSAGES_PER_S:.0f}; 0: no limit)")
    parser.add_argument("--max-node-messages-per-s", type=RATE,
                        help=f"messages per second per node socket, a second's worth at once "
                             f"(default {DEFAULT_MAX_NODE_MESSAGES_PER_S:.0f}; 0: no limit)")
    parser.add_argument("--scenes-dir", type=_folder, metavar="DIR",
                        help="folder of scene files (glTF/GLB/OBJ/PLY/STL, sub-folders too) that the viewer's "
                             "scene picker offers; read only (default: ./scenes when the folder you start from "
                             "has one)")
    parser.add_argument("--data-dir", type=_data_folder, metavar="DIR",
                        help="folder for uploaded scenes (DIR/scenes) and the sessions, which come back after a "
                             "restart (default: uploads go to your data folder, $XDG_DATA_HOME/tessera or "
                             "~/.local/share/tessera, and sessions are not kept; none: no uploads)")
    parser.add_argument("--max-upload-mb", type=_megabytes,
                        help=f"largest scene upload, MiB (default {defaults.max_upload_mb})")
    parser.add_argument("--upload-check-memory-mb", type=_megabytes,
                        help="memory (address space) of the process that loads an upload to check it, MiB; "
                             f"a file that needs more is refused with 413 (default {defaults.upload_check_memory_mb})")
    parser.add_argument("--max-sessions", type=_count,
                        help=f"sessions open at once, the default one included (default {defaults.max_sessions})")
    parser.add_argument("--session-idle-timeout-s", type=POSITIVE,
                        help="close a session that no viewer and no API call used for this long, s "
                             f"(default {defaults.session_idle_timeout_s:g}; never the default session)")
    parser.add_argument("--stream", choices=STREAM_MODES,
                        help="what viewers get while the picture changes: auto (default: H.264 video where the "
                             "browser decodes it, else VP9, else tiles), h264 (libx264, GPL), vp9 (libvpx, BSD) "
                             "or tiles (the nodes' JPEG tiles); still frames are exact images either way")
    parser.add_argument("--max-bitrate", type=_bitrate,
                        help="highest bitrate of a session's video, bit/s, k or M allowed (default "
                             f"{DEFAULT_MAX_BITRATE // 1_000_000}M); the stream follows each viewer's link below it")
    parser.add_argument("--max-size", type=parse_size,
                        help=f"largest frame of a session, WxH (default {defaults.max_size[0]}x{defaults.max_size[1]})")
    parser.add_argument("--max-jobs", type=_count,
                        help="render jobs (posters, films) under way at once across the sessions; more are refused "
                             f"with 503 (default {defaults.max_jobs})")
    parser.add_argument("--max-poster-size", type=parse_poster_size, metavar="WxH",
                        help="largest poster, WxH (default "
                             f"{defaults.max_poster_size[0]}x{defaults.max_poster_size[1]}, the most a poster may be)")
    parser.add_argument("--max-film-frames", type=_count,
                        help=f"most frames of a film (default {defaults.max_film_frames}: 10 minutes at 30 fps)")
    parser.add_argument("--root-path", type=_root_path,
                        help="path prefix a reverse proxy serves the coordinator under, e.g. /tessera (the proxy "
                             "strips it); the links the coordinator returns carry it. A proxy's X-Forwarded-Prefix "
                             "header wins (default: none)")
    return parser


def load_settings(argv: Sequence[str] | None = None, environ: dict[str, str] | None = None) -> Settings:
    """Settings from ``argv`` over ``TESSERA_*`` variables over defaults; exits with a message on bad values."""
    parser = build_parser()
    env = dict(os.environ if environ is None else environ)
    if env.get("TESSERA_JPEG_QUALITY") and not env.get("TESSERA_INTERACTIVE_QUALITY"):
        env["TESSERA_INTERACTIVE_QUALITY"] = env["TESSERA_JPEG_QUALITY"]
    env_args: list[str] = []
    for action in parser._actions:
        if not action.option_strings or action.dest == "help":
            continue
        key = "TESSERA_" + action.dest.upper()
        if env.get(key):
            env_args.append(f"{action.option_strings[0]}={env[key]}")
    merged = vars(parser.parse_args(env_args))
    merged.update({k: v for k, v in vars(parser.parse_args(argv)).items() if v is not None})
    values = {k: v for k, v in merged.items() if v is not None}
    if "node_slowdowns" in values:
        try:
            values["node_slowdowns"] = tuple(float(v) for v in values["node_slowdowns"].split(","))
        except ValueError:
            parser.error(f"--node-slowdowns must be numbers, got {values['node_slowdowns']!r}")
        if not all(math.isfinite(v) and v >= 1.0 for v in values["node_slowdowns"]):
            parser.error("--node-slowdowns must be finite numbers >= 1")
    if values.get("still_codec") == NO_STILL:
        values["still_codec"] = None
    if values.get("data_dir") == NO_DATA_DIR:
        del values["data_dir"]
    elif "data_dir" not in values:
        values["user_data_dir"] = user_data_dir(env)
    if "scenes_dir" not in values and SCENES_FOLDER.is_dir():
        values["scenes_dir"] = SCENES_FOLDER.resolve()
    try:
        settings = Settings(**values)
    except ValueError as exc:
        parser.error(str(exc))
    from tessera.balancers import BALANCERS

    if settings.balancer not in BALANCERS:
        parser.error(f"unknown balancer {settings.balancer!r}; choose one of {sorted(BALANCERS)}")
    return settings
