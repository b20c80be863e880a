"""The render node's settings: one typed object, parsed once at start-up from argv and the
environment (every ``--flag`` is also ``TESSERA_<FLAG>``; the command line wins)."""

from __future__ import annotations

import argparse
import hashlib
import os
import socket
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from node.container_name import DOCKER_MARKER, container_name, is_unexpanded_template
from node.culling.switch import CullMode
from node.gl.shading import AUTO_MSAA, FILTER_MSAA, MSAA_CHOICES, ShadingOptions
from node.scene.cache_folder import DEFAULT_CACHE_MB, CacheFolder
from node.scene.fetch import DEFAULT_CACHE_DIR
from node.scene.octree import DEFAULT_FACE_LIMIT
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
from tessera.geometry import DEFAULT_BACKGROUND
from tessera.points.budget import DEFAULT_POINT_BUDGET, DEFAULT_POINT_SIZE
from tessera.scheduling.refinement import (
    DEFAULT_MAX_STILL_SAMPLES,
    DEFAULT_STILL_SAMPLES,
    DEFAULT_STILL_TARGET_DB,
    StillPlan,
)
from tessera.wire.messages import MAX_LOD_ERROR_PX, MAX_POINT_SIZE, MAX_SIDE

DEFAULT_COORDINATOR = "ws://127.0.0.1:8000/ws/node"
DEFAULT_SCENE = "builtin:cluster"
DEFAULT_SIZE = (1280, 720)
#: The budget of the scenes a node holds at once, in MiB (:mod:`node.gl.resident`).
DEFAULT_SCENE_MEMORY_MB = 2048
parse_size = size_parser(1, MAX_SIDE)
ENV_PREFIX = "TESSERA_"


#: The kernel's id of this boot: one per machine, the same in every container on it.
BOOT_ID = Path("/proc/sys/kernel/random/boot_id")


def default_host() -> str:
    """This machine, as nodes that share its cores name it alike: a digest of the kernel's boot id
    (containers on one host see the same), else the host name."""
    try:
        boot = BOOT_ID.read_text().strip()
    except OSError:
        return socket.gethostname()[:64]
    return hashlib.sha256(boot.encode()).hexdigest()[:16]


def default_name() -> str:
    """In a Compose container, its name without the project (``node_2``: :mod:`node.container_name`);
    elsewhere ``hostname-pid``. Unique per process, readable in the coordinator's stats."""
    in_container = DOCKER_MARKER.exists() and container_name()
    return in_container or f"{socket.gethostname()}-{os.getpid()}"


@dataclass(frozen=True, slots=True)
class NodeSettings:
    """Everything the node process is configured with."""

    coordinator: str = DEFAULT_COORDINATOR
    name: str = field(default_factory=default_name)
    token: str | None = None
    slowdown: float = 1.0
    host: str = field(default_factory=default_host)
    render_once: Path | None = None
    scene: str = DEFAULT_SCENE
    camera: Path | None = None
    size: tuple[int, int] = DEFAULT_SIZE
    background: tuple[float, float, float] = DEFAULT_BACKGROUND
    culling: CullMode = CullMode.AUTO
    face_limit: int = DEFAULT_FACE_LIMIT
    time: float = 0.0
    objects: Path | None = None
    #: ``--render-once``: clip planes and section box (JSON file, :mod:`tessera.tools.clipping`).
    clip: Path | None = None
    #: ``--render-once``: the object drawn selected (tinted).
    highlight: str | None = None
    scene_memory_mb: int = DEFAULT_SCENE_MEMORY_MB
    scene_cache_dir: Path = DEFAULT_CACHE_DIR
    scene_cache_mb: int = DEFAULT_CACHE_MB
    msaa: int = AUTO_MSAA
    environment: Path | None = None
    #: ``--render-once``: the still's samples (the coordinator's default ``--still-samples``: adaptive,
    #: at most ``samples_max``, until its estimate reaches ``target_db``).
    samples: int = DEFAULT_STILL_SAMPLES
    samples_max: int = DEFAULT_MAX_STILL_SAMPLES
    target_db: float = DEFAULT_STILL_TARGET_DB
    #: ``--render-once``: the interactive frame (one sample, not shifted) instead of the still.
    interactive: bool = False
    #: ``--render-once --interactive``: the levels-of-detail bound in pixels (0: full detail).
    lod_error_px: float = 0.0
    #: ``--render-once`` of a point cloud: the interactive frame's point budget, the smallest splat side (px).
    point_budget: int = DEFAULT_POINT_BUDGET
    point_size: float = DEFAULT_POINT_SIZE

    @property
    def cache(self) -> CacheFolder:
        """The scene cache folder (``--scene-cache-dir``, ``--scene-cache-mb``)."""
        return CacheFolder(self.scene_cache_dir, self.scene_cache_mb << 20)

    @property
    def still_plan(self) -> StillPlan:
        """How ``--render-once`` samples the still."""
        return StillPlan(self.samples, self.samples_max, self.target_db)

    @property
    def shading(self) -> ShadingOptions:
        """How this node shades (``--msaa``, ``--environment``)."""
        return ShadingOptions(msaa=self.msaa, environment=self.environment)


#: A scene time in seconds.
parse_time = number_parser(note=" of seconds")
#: A smallest splat side in (0, MAX_POINT_SIZE] px (issue 36).
parse_point_size = number_parser(0.0, above=True, maximum=MAX_POINT_SIZE, note=" px")
#: A slowdown factor ≥ 1.
parse_slowdown = number_parser(1.0)


def parse_culling(text: str) -> CullMode:
    """One of hybrid, cpu, gpu, off."""
    try:
        return CullMode(text.strip().lower())
    except ValueError:
        choices = ", ".join(mode.value for mode in CullMode)
        raise argparse.ArgumentTypeError(f"culling must be one of {choices}, got {text!r}") from None


def positive_int_parser(what: str) -> Callable[[str], int]:
    """A parser of an integer ≥ 1; its error names ``what``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = 0
        if value < 1:
            raise argparse.ArgumentTypeError(f"{what} must be an integer >= 1, got {text!r}")
        return value

    return parse


parse_face_limit = positive_int_parser("face limit")
parse_scene_memory = positive_int_parser("scene memory")
parse_cache_size = positive_int_parser("scene cache size")
#: A levels-of-detail bound in pixels, 0 (full detail) … :data:`tessera.wire.messages.MAX_LOD_ERROR_PX`.
parse_lod_error = number_parser(0.0, note=" of pixels", maximum=MAX_LOD_ERROR_PX)


def parse_msaa(text: str) -> int:
    """``auto`` (:data:`node.gl.shading.AUTO_MSAA`), ``filter`` (:data:`node.gl.shading.FILTER_MSAA`)
    or one of :data:`node.gl.shading.MSAA_CHOICES`."""
    choices = ", ".join(["auto", "filter", *(str(value) for value in MSAA_CHOICES)])
    named = {"auto": AUTO_MSAA, "filter": FILTER_MSAA}
    if text.strip().lower() in named:
        return named[text.strip().lower()]
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value not in MSAA_CHOICES:
        raise argparse.ArgumentTypeError(f"msaa must be one of {choices}, got {text!r}")
    return value


def parse_host_id(text: str) -> str:
    if not 0 < len(text) <= 64:
        raise argparse.ArgumentTypeError(f"host id must be 1 to 64 characters, got {len(text)}")
    return text


def parse_coordinator(text: str) -> str:
    if not text.startswith(("ws://", "wss://")):
        raise argparse.ArgumentTypeError(f"coordinator must be a ws:// or wss:// URL, got {text!r}")
    return text


def build_parser(environ: Mapping[str, str]) -> argparse.ArgumentParser:
    """The ``python -m node`` parser; defaults come from ``TESSERA_<FLAG>`` variables in ``environ``."""
    parser = argparse.ArgumentParser(
        prog=command_name(sys.argv[0], "node"),
        description="Tessera render node: renders tiles for a coordinator, or one frame with --render-once.",
        epilog="Every flag can also be set as an environment variable TESSERA_<FLAG>, e.g. TESSERA_TOKEN.",
    )

    def add(flag: str, default: object, help_text: str, **kwargs: object) -> None:
        env_name = ENV_PREFIX + flag.lstrip("-").replace("-", "_").upper()
        parser.add_argument(flag, default=environ.get(env_name, default),
                            help=f"{help_text} [env {env_name}]", **kwargs)  # type: ignore[arg-type]

    add("--coordinator", DEFAULT_COORDINATOR, "coordinator URL, ws://HOST:PORT/ws/node, or wss://… through a TLS "
        "proxy (the certificate is checked against the system's CAs; SSL_CERT_FILE=CA.pem trusts another)",
        type=parse_coordinator)
    add("--name", None, "node name shown in the coordinator's stats (default hostname-pid; in a Compose container "
        "its name without the project, e.g. node_2; a name with '{{', an unexpanded Swarm template, is ignored)")
    add("--token", None, "shared secret the coordinator expects")
    add("--slowdown", 1.0, "emulate a node this many times slower (sleeps (F-1) x render time per tile)",
        type=parse_slowdown)
    add("--host-id", None, "the machine this node runs on, as the coordinator counts cores: a new session's scene is "
        "loaded by one node of a machine at a time, by nodes of other machines at once (default: this kernel's "
        "boot id, the same in every container on it)", dest="host", metavar="ID", type=parse_host_id)
    add("--render-once", None, "render one full frame to this PNG and exit (no coordinator)", type=Path,
        metavar="OUT.png")
    add("--scene", DEFAULT_SCENE, "scene file (glTF/GLB/OBJ/PLY/STL) or builtin:NAME, for --render-once")
    add("--camera", None, "camera JSON file for --render-once (a camera, or a saved GET /api/camera answer; "
        "default: frame the whole scene)", type=Path)
    add("--size", DEFAULT_SIZE, "frame size WxH for --render-once", type=parse_size)
    add("--background", DEFAULT_BACKGROUND, "clear colour '#rrggbb' or 'r,g,b' in 0..1 for --render-once",
        type=parse_background)
    add("--culling", CullMode.AUTO.value, "skip the geometry outside each tile before drawing it: hybrid (on the "
        "CPU, on the GPU where the CPU is slow), cpu, gpu, off, or auto (hybrid on a hardware GPU, cpu on llvmpipe)",
        type=parse_culling)
    add("--time", 0.0, "scene time in seconds for --render-once: the scene's animations are sampled there",
        type=parse_time)
    add("--objects", None, "object state JSON file for --render-once, {name: {translation, rotation, scale, "
        "visible}} (any subset of those)", type=Path, metavar="STATE.json")
    add("--clip", None, "clip planes and section box JSON file for --render-once, {planes: [{point, normal}], box: "
        "{min, max}, cap, cap_color} (as PUT /api/sessions/ID/clip takes)", type=Path, metavar="CLIP.json")
    add("--highlight", None, "--render-once draws this object selected (tinted, with its descendants)",
        metavar="NAME")
    add("--face-limit", DEFAULT_FACE_LIMIT, "split meshes into chunks of at most this many faces at load, so that each "
        "tile draws only the chunks it sees", type=parse_face_limit)
    add("--scene-memory-mb", DEFAULT_SCENE_MEMORY_MB, "memory for the scenes a node holds at once (their vertex "
        "and index buffers, levels of detail and arrays); after a load the least recently used others are released "
        "until they fit; a scene that fits only without its levels of detail is drawn at full detail",
        type=parse_scene_memory, metavar="MB")
    add("--scene-cache-dir", DEFAULT_CACHE_DIR, "folder of the scene cache: every scene file is read once into "
        "ready-to-draw arrays kept here by its SHA-256 and mapped on the next load, by any node sharing the folder "
        "(also the files fetched from the coordinator); delete its contents to clear it", type=Path, metavar="DIR")
    add("--scene-cache-mb", DEFAULT_CACHE_MB, "size bound of the scene cache folder: after each new entry the "
        "least recently used ones are deleted until it fits", type=parse_cache_size, metavar="MB")
    add("--msaa", "auto", "anti-aliasing of tiles and whole frames: 1 (off), 2, 4 or 8 samples per pixel (capped at "
        "what the GL offers; on llvmpipe 2 is two samples drawn as a frame twice as wide and resolved by a 3x3 "
        "filter, 1.2-2.0x the frame time of filter, where 4 multisamples cost 2.6-3.5x that of 1), filter (1 sample "
        "resolved by the 3x3 filter, 1.1-1.2x that of 1), or auto: 4 on a GPU, 2 on llvmpipe; depth layers (hybrid, "
        "sort-last) are drawn at 1, unfiltered", type=parse_msaa, metavar="N")
    add("--environment", None, "Radiance .hdr environment (equirectangular) lighting the scene; default a "
        "neutral studio generated at start-up", type=Path, metavar="FILE.hdr")
    add("--samples", "auto", "--render-once renders the still of this many jittered samples, or auto (default): "
        "until it converges, as the coordinator's --still-samples default, so the image is the still it converges to",
        type=parse_still_samples, metavar="N")
    add("--samples-max", str(DEFAULT_MAX_STILL_SAMPLES), "most samples of --render-once's adaptive still (the "
        "coordinator's --still-samples-max)", type=parse_samples_max, metavar="N")
    add("--target-db", repr(DEFAULT_STILL_TARGET_DB), "--render-once's adaptive still stops once its estimated PSNR "
        "against its converged image reaches this, dB (the coordinator's --still-target-db)", type=parse_target_db,
        metavar="DB")
    add("--lod-error-px", 0.0, "--render-once --interactive draws the levels of detail whose error on screen is at "
        "most this many pixels, as a serving node draws a moving frame with the coordinator's bound (0: full "
        "detail)", type=parse_lod_error, metavar="PX")
    add("--point-budget", DEFAULT_POINT_BUDGET, "--render-once --interactive of a point cloud draws at most this "
        "many points, as a serving node draws a moving frame within the coordinator's budget (the point_budget "
        "of its stats); the still draws every point in view, as the coordinator's still converges to",
        type=parse_point_budget, metavar="N")
    add("--point-size", DEFAULT_POINT_SIZE, "--render-once of a point cloud draws each point as a square at least "
        "this many pixels wide (the coordinator's --point-size)", type=parse_point_size, metavar="PX")
    parser.add_argument("--interactive", action="store_true",
                        help="--render-once renders the interactive frame (one sample, not shifted), not the still")
    return parser


def parse_settings(argv: Sequence[str] | None = None, environ: Mapping[str, str] | None = None) -> NodeSettings:
    """Settings from ``argv`` (default ``sys.argv[1:]``) over ``environ`` (default ``os.environ``);
    exits with a usage message on invalid values, as argparse does."""
    args = build_parser(os.environ if environ is None else environ).parse_args(argv)
    values = {key: value for key, value in vars(args).items() if value is not None and value != ""}
    if is_unexpanded_template(values.get("name", "")):
        del values["name"]
    return NodeSettings(**values)
