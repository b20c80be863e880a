"""The real deployment: the image from the Dockerfile, run by docker-compose.yml under Compose and
unchanged under Swarm (`docker stack deploy`), with docker-compose.tls.yml's TLS proxy in front.

Builds the images (scripts/docker-base, then `compose build`), starts a coordinator and three
render nodes, checks a composited frame against ``python -m node --render-once`` on the host, the
viewer in headless Chromium, that node containers are named by service and replica, that every
container is read-only with no capabilities, a killed node container, a rejoin, an uploaded scene
rendered by a node container without the scenes folder (its bytes fetched from the coordinator by
SHA-256) and kept with its session by a new coordinator container (the named volume), and that
`down -v` leaves nothing. Then the TLS proxy: the API, frames, a
``wss://`` viewer socket, a node on the host joining over ``wss://``, the viewer page over https, a
self-signed and a mounted certificate. Without Docker the tests skip, except in CI (CI=true), where
they fail.
"""

from __future__ import annotations

import base64
import contextlib
import hashlib
import io
import json
import os
import shutil
import socket
import ssl
import subprocess
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np
import pytest
import websockets.sync.client as ws_client
from PIL import Image

from bench.processes import orbit
from server.routes.deps import TOKEN_COOKIE
from tessera.wire.protocol import unpack_frame
from tests.browser_support import DRAWN_FRACTION_JS, chromium_context, unavailable
from tests.conftest import PYTHON, REPO, SCENES, scene_path, seconds, start_process
from tests.integration_support import (
    assert_matches_reference,
    fetch_frame,
    orbit_cameras,
    ready_nodes,
    render_once,
    stats,
    wait_until,
)

pytestmark = [pytest.mark.docker, pytest.mark.timeout(1500)]

SIZE = (320, 240)
TOKEN = "docker-test-token"
SCENE = "bunny/bun_zipper.ply"
#: A small textured GLB for the upload: not in the coordinator's /data until uploaded.
UPLOAD = "gltf_small/Duck.glb"
#: Compose v1 names a service's containers PROJECT_node_1, v2 PROJECT-node-1.
NODE_NAMES = ({"node_1", "node_2", "node_3"}, {"node-1", "node-2", "node-3"})
COMPOSE_FILES = ["-f", "docker-compose.yml"]
TLS_COMPOSE_FILES = [*COMPOSE_FILES, "-f", "docker-compose.tls.yml"]


def run(args: list[str], env: dict[str, str] | None = None, timeout: float = 120.0) -> str:
    """Run a command in the repository; fail the test with its output when it fails."""
    result = subprocess.run(args, cwd=REPO, env={**os.environ, **(env or {})}, capture_output=True, text=True,
                            timeout=seconds(timeout))
    assert result.returncode == 0, f"{' '.join(args)} exited {result.returncode}:\n{result.stdout}\n{result.stderr}"
    return result.stdout


def report(request: pytest.FixtureRequest, line: str) -> None:
    """A measurement on the terminal, shown whether or not output is captured."""
    capture = request.config.pluginmanager.get_plugin("capturemanager")
    terminal = request.config.pluginmanager.get_plugin("terminalreporter")
    if capture is not None and terminal is not None:
        with capture.global_and_fixture_disabled():
            terminal.write_line(f"[docker] {line}")


def compose_command() -> list[str] | None:
    """`docker compose` (v2 plugin) where installed, else the standalone `docker-compose` (v1)."""
    if subprocess.run(["docker", "compose", "version"], capture_output=True).returncode == 0:
        return ["docker", "compose"]
    return ["docker-compose"] if shutil.which("docker-compose") else None


def free_ports(count: int) -> list[int]:
    """``count`` distinct free loopback ports (all bound at once, so none repeats)."""
    with contextlib.ExitStack() as stack:
        probes = [stack.enter_context(socket.socket()) for _ in range(count)]
        for probe in probes:
            probe.bind(("127.0.0.1", 0))
        return [probe.getsockname()[1] for probe in probes]


def labelled(kind: str, label: str) -> list[str]:
    """IDs of containers or networks (kind) carrying a label, running or not."""
    listing = ["docker", "ps", "-a"] if kind == "container" else ["docker", "network", "ls"]
    return run([*listing, "-q", "--filter", f"label={label}"]).split()


@pytest.fixture(scope="module")
def compose(request) -> list[str]:
    """The Compose command line, after building the image; skips (fails in CI) without Docker."""
    command = compose_command() if shutil.which("docker") else None
    usable = command is not None and subprocess.run(["docker", "info"], capture_output=True).returncode == 0
    if not usable:
        unavailable("needs a running Docker engine and docker compose (or docker-compose)")
    started = time.monotonic()
    run([str(REPO / "scripts" / "docker-base")], timeout=900)
    base_done = time.monotonic()
    run([*command, *TLS_COMPOSE_FILES, "build"], timeout=900)
    built = time.monotonic()
    report(request, f"scripts/docker-base {base_done - started:.1f} s, "
                    f"compose build (tessera and the TLS proxy) {built - base_done:.1f} s")
    remove_stale_builder_images()
    return command


def remove_stale_builder_images() -> None:
    """Remove the untagged images of the Dockerfile's build stages (label tessera.stage=builder) left
    by earlier builds, keeping the ones this build used: they cache the dependency layers."""
    current = {run(["docker", "build", "--quiet", "--target", stage, "."]).strip()
               for stage in ("requirements", "builder")}
    left = set(run(["docker", "images", "--quiet", "--no-trunc", "--filter", "label=tessera.stage=builder",
                    "--filter", "dangling=true"]).split())
    if left - current:
        run(["docker", "rmi", *sorted(left - current)])
    assert current <= left, "the build stages' images are labelled"


@dataclass
class Deployment:
    """A running Compose project and a client for its coordinator."""

    compose: list[str]
    env: dict[str, str]
    client: httpx.Client

    def run(self, *args: str) -> str:
        return run([*self.compose, "-p", self.env["COMPOSE_PROJECT_NAME"], *args], env=self.env, timeout=300)

    def containers(self, service: str | None = None) -> list[str]:
        """IDs of the project's running containers, of one service or all."""
        service_filter = ["--filter", f"label=com.docker.compose.service={service}"] if service else []
        return run(["docker", "ps", "-q", "--filter", f"label=com.docker.compose.project={self.project}",
                    *service_filter]).split()

    def node_containers(self) -> list[str]:
        return self.containers("node")

    @property
    def project(self) -> str:
        return self.env["COMPOSE_PROJECT_NAME"]


def deployment_env(port: int, **extra: str) -> dict[str, str]:
    """The compose file's variables; empty ones take the file's defaults whatever this shell has set."""
    return {"TESSERA_PORT": str(port), "TESSERA_TOKEN": TOKEN, "TESSERA_CODEC": "png",
            "TESSERA_SIZE": f"{SIZE[0]}x{SIZE[1]}", "TESSERA_BALANCER": "", "TESSERA_SCENE": "",
            "TESSERA_SCENES_DIR": "", "TESSERA_IMAGE": "", "TESSERA_RESTART": "no", "TESSERA_INTERACTIVE_QUALITY": "",
            "TESSERA_STILL_CODEC": "", "TESSERA_TLS_PORT": "", "TESSERA_TLS_DIR": "", "TESSERA_TLS_NAMES": "",
            "TESSERA_PROXY_IMAGE": "", "TESSERA_MODE": "", "TESSERA_DEPTH_STRIP": "", "TESSERA_MAX_UPLOAD_MB": "",
            "TESSERA_UPLOAD_CHECK_MEMORY_MB": "",
            # Moving frames at full detail: they are compared with --render-once --interactive.
            "TESSERA_LOD_ERROR_PX": "0", **extra}


def coordinator_client(port: int) -> httpx.Client:
    return httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=seconds(30),
                        headers={"Authorization": f"Bearer {TOKEN}"})


def wait_serving(client: httpx.Client, timeout: float) -> None:
    def healthy() -> bool:
        try:
            return client.get("/healthz").status_code == 200
        except httpx.TransportError:
            return False

    wait_until(healthy, timeout, "GET /healthz == 200")


@contextlib.contextmanager
def deployed(compose: list[str], files: list[str], port: int, nodes: int, **extra: str) -> Iterator[Deployment]:
    """`compose up -d --scale node=N` of a fresh project from ``files``, serving on ``port``;
    `down -v` at the end."""
    env = deployment_env(port, COMPOSE_PROJECT_NAME=f"tessera-test-{uuid.uuid4().hex[:8]}", **extra)
    with coordinator_client(port) as client:
        deployment = Deployment([*compose, *files], env, client)
        try:
            deployment.run("up", "-d", "--scale", f"node={nodes}")
            wait_serving(client, seconds(120))
            yield deployment
        finally:
            deployment.run("down", "-v", "--remove-orphans", "--timeout", "10")


@pytest.fixture(scope="module")
def deployment(compose) -> Iterator[Deployment]:
    """`compose up -d --scale node=3` with the real bunny from the mounted scenes folder."""
    scene_path(SCENE)
    with deployed(compose, COMPOSE_FILES, free_ports(1)[0], 3, TESSERA_SCENES_DIR=str(SCENES),
                  TESSERA_SCENE=f"/scenes/{SCENE}") as deployment:
        yield deployment


def health(container: str) -> str:
    return run(["docker", "inspect", "-f", "{{.State.Health.Status}}", container]).strip()


def assert_hardened(container: str, no_new_privileges: bool = True) -> None:
    """A read-only root filesystem with a writable /tmp, every capability dropped and (unless told
    otherwise: Swarm ignores it) no-new-privileges: as configured (docker inspect) and as the kernel
    applies them to the container's main process (/proc/1/status)."""
    info = json.loads(run(["docker", "inspect", container]))[0]
    host, name = info["HostConfig"], info["Name"]
    assert host["ReadonlyRootfs"], f"{name}: the root filesystem is writable"
    assert host["CapDrop"] == ["ALL"] and not host["CapAdd"] and not host["Privileged"], \
        f"{name}: CapDrop {host['CapDrop']}, CapAdd {host['CapAdd']}, Privileged {host['Privileged']}"
    status = dict(line.split(":", 1) for line in run(["docker", "exec", container, "cat", "/proc/1/status"])
                  .splitlines() if ":" in line)
    capabilities = {key: int(status[key], 16) for key in ("CapInh", "CapPrm", "CapEff", "CapBnd", "CapAmb")}
    assert not any(capabilities.values()), f"{name}: capabilities left {capabilities}"
    if no_new_privileges:
        assert "no-new-privileges:true" in (host["SecurityOpt"] or []), f"{name}: {host['SecurityOpt']}"
        assert status["NoNewPrivs"].strip() == "1", f"{name}: NoNewPrivs {status['NoNewPrivs'].strip()}"
    write = subprocess.run(["docker", "exec", container, "touch", "/write-probe"], capture_output=True, text=True)
    assert write.returncode != 0 and "Read-only file system" in write.stderr, f"{name}: {write.stderr!r}"
    run(["docker", "exec", container, "sh", "-c", "touch /tmp/write-probe && rm /tmp/write-probe"])


def test_three_containers_composite_the_reference_frame(deployment, tmp_path):
    client = deployment.client
    wait_until(lambda: len(ready_nodes(client)) == 3, seconds(120), "3 ready nodes in /api/stats")
    bounds = wait_until(lambda: client.get("/api/camera").json()["bounds"], seconds(60), "scene bounds")
    camera = orbit_cameras(bounds, 1)[0]
    first = client.put("/api/camera", json=camera).raise_for_status().json()["frame"]
    frame_id, frame = fetch_frame(client, first)
    assert frame_id >= first
    assert_matches_reference(frame, render_once(str(scene_path(SCENE)), camera, SIZE, tmp_path), "compose x3")
    # "tiles": each node's part of the latest frame whose timings are all in, which may be a later
    # frame than the one fetched (CI under load once found a node without any there)
    wait_until(lambda: all(node["tiles"] for node in stats(client)["nodes"]), seconds(30),
               "every container rendering part of a frame")
    containers = run(["docker", "ps", "-q", "--filter", f"label=com.docker.compose.project={deployment.project}"])
    wait_until(lambda: all(health(c) == "healthy" for c in containers.split()), seconds(90),
               "every container's healthcheck to pass")


def test_node_containers_are_named_by_service_and_replica(deployment):
    names = {node["name"] for node in wait_until(lambda: len(ready_nodes(deployment.client)) == 3 and
                                                  ready_nodes(deployment.client), seconds(120), "3 ready nodes")}
    assert names in NODE_NAMES, f"node names {names}"


def test_viewer_from_the_host_draws_a_frame_and_shows_the_node_names(deployment, tmp_path):
    names = sorted(node["name"] for node in ready_nodes(deployment.client))
    with chromium_context(tmp_path / "chromium-profile") as context:
        page = context.new_page()
        page.goto(f"{deployment.client.base_url}/?token={TOKEN}")
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=seconds(60) * 1000, polling=100)
        assert page.evaluate("window.tessera.framesDrawn") > 0
        shown = "() => [...document.querySelectorAll('#nodes .name')].map((e) => e.textContent).sort()"
        page.wait_for_function(f"() => ({shown})().join() === {json.dumps(','.join(names))}",
                               timeout=seconds(30) * 1000, polling=100)
        cut = page.evaluate("() => [...document.querySelectorAll('#nodes .name')]"
                            ".filter((e) => e.scrollWidth > e.clientWidth).map((e) => e.textContent)")
        assert cut == [], f"names cut off in the panel: {cut}"
        # The picker offers the mounted scenes folder's files (issue 38).
        page.wait_for_function("() => [...document.querySelectorAll('#scene-pick option')].some("
                               f"(o) => o.value === {json.dumps('library/' + SCENE)})", timeout=seconds(30) * 1000)
        assert not page.is_visible("#library-hint") and "drop a scene file" in page.text_content("#upload-hint")


def test_containers_are_read_only_without_capabilities(deployment):
    containers = deployment.containers()
    assert len(containers) == 4, "a coordinator and 3 nodes"
    for container in containers:
        assert_hardened(container)
    # ... and they serve frames so: the tests before and after this one fetch them.


def test_killed_node_container_frames_resume_and_it_rejoins(deployment, tmp_path, request):
    client = deployment.client
    wait_until(lambda: len(ready_nodes(client)) == 3, seconds(120), "3 ready nodes")
    cameras = orbit_cameras(client.get("/api/camera").json()["bounds"], 3)
    fetch_frame(client, client.put("/api/camera", json=cameras[0]).json()["frame"])

    victim = deployment.node_containers()[0]
    killed_at = time.monotonic()
    run(["docker", "kill", victim])
    wait_until(lambda: len(stats(client)["nodes"]) == 2, seconds(60), "the killed node to leave /api/stats")
    left_at = time.monotonic()
    after_kill = client.put("/api/camera", json=cameras[1]).json()["frame"]
    _, frame = fetch_frame(client, after_kill)
    resumed_at = time.monotonic()
    report(request, f"docker kill → node dropped {left_at - killed_at:.2f} s, "
                    f"→ first frame from 2 nodes {resumed_at - killed_at:.2f} s")
    assert_matches_reference(frame, render_once(str(scene_path(SCENE)), cameras[1], SIZE, tmp_path), "2 nodes")
    assert len(deployment.node_containers()) == 2

    deployment.run("up", "-d", "--no-recreate", "--scale", "node=3")
    wait_until(lambda: len(ready_nodes(client)) == 3, seconds(120), "the third node to rejoin")
    rejoined = client.put("/api/camera", json=cameras[2]).json()["frame"]
    _, frame = fetch_frame(client, rejoined)
    turns = iter(range(1_000_000))

    def all_render_while_the_camera_moves() -> bool:
        """A frame renders only on a change, and a newcomer's first tile may be backed up by the
        others (its warm-up can pass the straggler floor on a busy machine): move on until each
        of the 3 nodes rendered part of a frame."""
        client.put("/api/camera", json=cameras[next(turns) % len(cameras)])
        return all(node["tiles"] for node in stats(client)["nodes"])

    wait_until(all_render_while_the_camera_moves, seconds(60), "tiles for all 3 nodes", interval=0.2)
    report(request, f"scale back to 3 → rejoined and rendering {time.monotonic() - resumed_at:.2f} s")
    assert_matches_reference(frame, render_once(str(scene_path(SCENE)), cameras[2], SIZE, tmp_path), "rejoined")


def session_frame(client: httpx.Client, session_id: str, after: int) -> np.ndarray:
    """The session's first complete frame with id >= ``after``: (h, w, 3) uint8."""
    response = client.get(f"/api/sessions/{session_id}/frame.png", params={"after": after}, timeout=seconds(120))
    response.raise_for_status()
    return np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))


def holds_file(container: str, path: str) -> bool:
    return subprocess.run(["docker", "exec", container, "test", "-f", path], capture_output=True).returncode == 0


def test_an_upload_reaches_a_node_without_the_scenes_and_survives_a_new_coordinator(deployment, tmp_path, request):
    """Upload a scene and open a session of it; a node container with no /scenes mount (as on
    another host) joins and fetches the file from the coordinator by its SHA-256; the coordinator's
    container is then removed and created again: the upload and the session come back from the
    named volume and render the same picture."""
    client = deployment.client
    wait_until(lambda: len(ready_nodes(client)) == 3, seconds(120), "3 ready nodes")
    content = scene_path(UPLOAD).read_bytes()
    uploaded = client.post("/api/scenes", files={"file": ("duck.glb", content)})
    assert uploaded.status_code == 201, uploaded.text
    name, sha256 = uploaded.json()["name"], uploaded.json()["sha256"]
    assert sha256 == hashlib.sha256(content).hexdigest()
    created = client.post("/api/sessions", json={"scene": name, "size": list(SIZE)})
    assert created.status_code == 201, created.text
    session_id = created.json()["id"]
    bounds = wait_until(lambda: client.get(f"/api/sessions/{session_id}/camera").json()["bounds"], seconds(120),
                        "the uploaded scene's bounds")
    cameras = orbit_cameras(bounds, 2)
    reference = render_once(str(scene_path(UPLOAD)), cameras[0], SIZE, tmp_path)
    first = client.put(f"/api/sessions/{session_id}/camera", json=cameras[0]).raise_for_status().json()["frame"]
    assert_matches_reference(session_frame(client, session_id, first), reference, "uploaded scene, compose x3")
    cached = f"/var/cache/tessera/{sha256}.glb"
    assert all(holds_file(node, cached) for node in deployment.node_containers()), "the nodes' cache volume"

    outsider = f"{deployment.project}-no-scenes"
    run(["docker", "run", "--detach", "--rm", "--name", outsider, "--network", f"{deployment.project}_default",
         "--read-only", "--cap-drop", "ALL", "--security-opt", "no-new-privileges:true",
         "--mount", "type=tmpfs,destination=/tmp", "--env", "TESSERA_COORDINATOR=ws://coordinator:8000/ws/node",
         "--env", f"TESSERA_TOKEN={TOKEN}", "--env", "MESA_SHADER_CACHE_DISABLE=true",
         "--env", "TESSERA_NAME=no-scenes", "tessera:latest", "python", "-m", "node"])
    try:
        assert run(["docker", "exec", outsider, "sh", "-c", "test -e /scenes || echo absent"]).strip() == "absent"
        wait_until(lambda: holds_file(outsider, f"/tmp/tessera-scenes/{sha256}.glb"), seconds(120),
                   "the node without /scenes to fetch the upload by its SHA-256")
        wait_until(lambda: "no-scenes" in {node["name"] for node in ready_nodes(client)}, seconds(120),
                   "the node without /scenes ready")
        turns = iter(range(1_000_000))

        def outsider_renders() -> bool:
            client.put(f"/api/sessions/{session_id}/camera", json=cameras[next(turns) % 2])
            return any(node["name"] == "no-scenes" and node["tiles_rendered"] for node in stats(client)["nodes"])

        wait_until(outsider_renders, seconds(60), "tiles from the node without /scenes", interval=0.2)
        # A camera of its own, so the frame after it is drawn by the four nodes.
        third = orbit(cameras[1], 0.3)
        after = client.put(f"/api/sessions/{session_id}/camera", json=third).raise_for_status().json()["frame"]
        assert_matches_reference(session_frame(client, session_id, after),
                                 render_once(str(scene_path(UPLOAD)), third, SIZE, tmp_path), "with the node")
    finally:
        run(["docker", "rm", "--force", outsider])

    replaced_at = time.monotonic()
    old_container = deployment.containers("coordinator")
    deployment.run("rm", "--stop", "--force", "coordinator")
    deployment.run("up", "-d", "--no-deps", "coordinator")
    assert deployment.containers("coordinator") != old_container, "a new coordinator container"
    wait_serving(client, seconds(120))
    wait_until(lambda: len(ready_nodes(client)) == 3, seconds(120), "the nodes back on the new coordinator")
    report(request, f"coordinator container replaced → 3 nodes back {time.monotonic() - replaced_at:.1f} s")
    assert {"name": name, "format": "glb", "bytes": len(content)} in client.get("/api/scenes").json()
    session = client.get(f"/api/sessions/{session_id}")
    assert session.status_code == 200, session.text
    assert session.json()["scene"] == name and session.json()["size"] == list(SIZE)
    restored = client.get(f"/api/sessions/{session_id}/camera").json()
    assert restored["camera"]["eye"] == pytest.approx(third["eye"]), "the session's camera came back"
    wait_until(lambda: client.get(f"/api/sessions/{session_id}").json()["state"] == "ready", seconds(120),
               "the restored session's scene on the nodes")
    again = client.put(f"/api/sessions/{session_id}/camera", json=cameras[0]).raise_for_status().json()["frame"]
    assert_matches_reference(session_frame(client, session_id, again), reference, "after a new coordinator")


def test_down_leaves_nothing_running(deployment):
    label = f"com.docker.compose.project={deployment.project}"
    assert labelled("container", label), "the project should be running before down"
    deployment.run("down", "-v", "--remove-orphans", "--timeout", "10")
    assert labelled("container", label) == []
    assert labelled("network", label) == []
    assert run(["docker", "volume", "ls", "-q", "--filter", f"label={label}"]).split() == [], "down -v keeps no volume"


@pytest.fixture
def swarm() -> Iterator[None]:
    """A single-node Swarm on the loopback address; left again only if this fixture created it."""
    state = run(["docker", "info", "-f", "{{.Swarm.LocalNodeState}}"]).strip()
    created = state == "inactive"
    had_gateway_bridge = bool(run(["docker", "network", "ls", "-q", "--filter", "name=^docker_gwbridge$"]).split())
    if created:
        run(["docker", "swarm", "init", "--advertise-addr", "127.0.0.1"])
    try:
        yield
    finally:
        if created:
            run(["docker", "swarm", "leave", "--force"])
            if not had_gateway_bridge:
                run(["docker", "network", "rm", "docker_gwbridge"])


def test_stack_deploy_serves_frames_on_a_swarm(compose, swarm, tmp_path):
    stack = f"tessera-test-{uuid.uuid4().hex[:8]}"
    port, = free_ports(1)
    env = deployment_env(port)
    label = f"com.docker.stack.namespace={stack}"
    try:
        run(["docker", "stack", "deploy", "--resolve-image", "never", "-c", "docker-compose.yml", stack], env=env)
        with coordinator_client(port) as client:
            wait_serving(client, seconds(120))
            nodes = wait_until(lambda: len(ready_nodes(client)) == 3 and ready_nodes(client), seconds(180),
                               "3 ready Swarm nodes")
            assert {node["name"] for node in nodes} == {f"{stack}_node.{slot}" for slot in (1, 2, 3)}, \
                "Swarm task names from TESSERA_NAME's template"
            camera = orbit_cameras(client.get("/api/camera").json()["bounds"], 1)[0]
            _, frame = fetch_frame(client, client.put("/api/camera", json=camera).json()["frame"])
            assert_matches_reference(frame, render_once("builtin:cluster", camera, SIZE, tmp_path), "swarm x3")
    finally:
        def removed() -> bool:
            # `docker stack rm` gives up on a network a stopping task still uses: asked again until it is gone.
            subprocess.run(["docker", "stack", "rm", stack], cwd=REPO, capture_output=True, timeout=seconds(120))
            return not labelled("container", label) and not labelled("network", label)

        wait_until(removed, seconds(120), f"stack {stack} to be removed", interval=2.0)
        volumes = run(["docker", "volume", "ls", "-q", "--filter", f"label={label}"]).split()
        if volumes:  # `docker stack rm` keeps the stack's named volumes
            run(["docker", "volume", "rm", *volumes])



# TLS: docker-compose.tls.yml's nginx proxy in front of a deployment of its own (the coordinator,
# one node container, builtin:cluster), verified against the proxy's certificate everywhere but the
# browser, which is told to accept that one certificate's key.

TLS_SCENE = "builtin:cluster"


def openssl(workdir: Path, *args: str) -> str:
    """The host's openssl, run in ``workdir``; its standard output."""
    result = subprocess.run(["openssl", *args], cwd=workdir, capture_output=True, text=True, timeout=seconds(60))
    assert result.returncode == 0, f"openssl {' '.join(args)} exited {result.returncode}:\n{result.stderr}"
    return result.stdout


def make_certificates(folder: Path) -> Path:
    """A test CA and, signed by it, ``folder``/cert.pem and key.pem for localhost and 127.0.0.1,
    readable by the proxy's user (uid 10001); returns the CA certificate, kept outside ``folder``."""
    folder.mkdir()
    folder.chmod(0o755)
    workdir = folder.parent
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    openssl(workdir, "req", "-x509", *ec, "-days", "2", "-subj", "/CN=Tessera test CA",
            "-keyout", "ca-key.pem", "-out", "ca.pem")
    openssl(workdir, "req", "-new", *ec, "-subj", "/CN=localhost", "-keyout", str(folder / "key.pem"),
            "-out", "server.csr")
    (workdir / "server.ext").write_text(
        "basicConstraints = critical, CA:FALSE\nkeyUsage = critical, digitalSignature\n"
        "extendedKeyUsage = serverAuth\nsubjectAltName = DNS:localhost, IP:127.0.0.1\n"
        "subjectKeyIdentifier = hash\nauthorityKeyIdentifier = keyid\n")
    openssl(workdir, "x509", "-req", "-in", "server.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem",
            "-CAcreateserial", "-days", "2", "-extfile", "server.ext", "-out", str(folder / "cert.pem"))
    for name in ("cert.pem", "key.pem"):
        (folder / name).chmod(0o644)
    return workdir / "ca.pem"


def spki_sha256(certificate: Path) -> str:
    """Base64 SHA-256 of a certificate's public key (SubjectPublicKeyInfo), as Chromium's
    ``--ignore-certificate-errors-spki-list`` takes it."""
    pem = openssl(certificate.parent, "x509", "-in", str(certificate), "-pubkey", "-noout")
    der = base64.b64decode("".join(line for line in pem.splitlines() if not line.startswith("-----")))
    return base64.b64encode(hashlib.sha256(der).digest()).decode()


@dataclass
class TlsProxy:
    """The proxy in front of a deployment, and the certificate the tests trust for it."""

    deployment: Deployment
    port: int
    workdir: Path
    no_certificates: Path
    trusted: Path | None = None

    @property
    def url(self) -> str:
        return f"https://127.0.0.1:{self.port}"

    def ssl_context(self) -> ssl.SSLContext:
        """Verifies the proxy against ``trusted`` alone (host name included): no verify=False."""
        assert self.trusted is not None
        return ssl.create_default_context(cafile=str(self.trusted))

    def client(self, token: str | None = TOKEN) -> httpx.Client:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return httpx.Client(base_url=self.url, verify=self.ssl_context(), timeout=seconds(30), headers=headers)

    def container(self) -> str:
        containers = self.deployment.containers("proxy")
        assert len(containers) == 1, f"one proxy container, found {containers}"
        return containers[0]

    def served_certificate(self) -> bytes | None:
        """The certificate the proxy presents (DER, not verified here), or None while it does not answer."""
        try:
            return ssl.PEM_cert_to_DER_cert(ssl.get_server_certificate(("127.0.0.1", self.port), timeout=5))
        except OSError:
            return None

    def start(self, tls_dir: Path, ca: Path | None = None) -> None:
        """(Re)create the proxy with TESSERA_TLS_DIR=``tls_dir`` and wait until /healthz answers over
        verified TLS: trusting ``ca``, or with none the self-signed certificate the proxy made,
        read from its container and checked to be the one it serves."""
        self.deployment.env["TESSERA_TLS_DIR"] = str(tls_dir)
        self.deployment.run("up", "-d", "proxy")  # recreates it when the folder changed, else a no-op
        served = wait_until(self.served_certificate, seconds(60), "a TLS handshake with the proxy")
        if ca is None:
            pem = run(["docker", "exec", self.container(), "cat", "/tmp/tls/cert.pem"])
            assert ssl.PEM_cert_to_DER_cert(pem) == served, "the proxy serves the certificate it made"
            ca = self.workdir / f"self-signed-{uuid.uuid4().hex[:8]}.pem"
            ca.write_text(pem)
        self.trusted = ca
        with self.client() as client:
            wait_serving(client, seconds(60))


@pytest.fixture(scope="module")
def tls(compose, tmp_path_factory) -> Iterator[TlsProxy]:
    """docker-compose.yml and docker-compose.tls.yml on free ports, one node container; the proxy
    makes its self-signed certificate (TESSERA_TLS_DIR is an empty folder)."""
    port, tls_port = free_ports(2)
    workdir = tmp_path_factory.mktemp("tls")
    no_certificates = workdir / "no-certificates"
    no_certificates.mkdir()
    no_certificates.chmod(0o755)
    with deployed(compose, TLS_COMPOSE_FILES, port, 1, TESSERA_TLS_PORT=str(tls_port),
                  TESSERA_TLS_DIR=str(no_certificates)) as deployment:
        proxy = TlsProxy(deployment, tls_port, workdir, no_certificates)
        proxy.start(no_certificates)
        yield proxy


def tls_cameras(client: httpx.Client) -> list[dict]:
    return orbit_cameras(wait_until(lambda: client.get("/api/camera").json()["bounds"], seconds(60), "bounds"), 3)


def wss_viewer_frame(proxy: TlsProxy, camera: dict, seq: int) -> np.ndarray:
    """A viewer socket over ``wss://`` (verified) turns the camera (input ``seq``) and reads frames
    until a TFRM frame answers it; that frame's tiles composited, (h, w, 3) uint8."""
    with ws_client.connect(f"wss://127.0.0.1:{proxy.port}/ws/view", ssl=proxy.ssl_context(),
                           additional_headers={"Authorization": f"Bearer {TOKEN}"}, max_size=64 << 20,
                           open_timeout=seconds(30)) as ws:
        assert json.loads(ws.recv(timeout=seconds(30)))["type"] == "hello"
        ws.send(json.dumps({"type": "camera", "camera": camera, "seq": seq}))
        frame = None
        while frame is None or frame.input_seq < seq:
            message = ws.recv(timeout=seconds(60))
            if isinstance(message, bytes):
                frame = unpack_frame(message)
    assert frame.size == SIZE and frame.tiles
    image = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    for entry, data in frame.tiles:
        r = entry.rect
        image[r.y:r.y + r.h, r.x:r.x + r.w] = np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))
    return image


def test_tls_api_and_frames_over_https(tls, tmp_path):
    with tls.client() as client:
        wait_until(lambda: len(ready_nodes(client)) == 1, seconds(120), "the node container ready")
        camera = tls_cameras(client)[0]
        _, frame = fetch_frame(client, client.put("/api/camera", json=camera).raise_for_status().json()["frame"])
        assert_matches_reference(frame, render_once(TLS_SCENE, camera, SIZE, tmp_path), "frame.png over https")
    with tls.client(token=None) as anonymous:
        assert anonymous.get("/api/stats").status_code == 401, "the token guards /api through the proxy"
        assert anonymous.get("/healthz").status_code == 200
        metrics = anonymous.get("/metrics")
        assert metrics.status_code == 200 and "tessera_frame_id" in metrics.text, "/metrics stays open"
    with pytest.raises(httpx.ConnectError, match="CERTIFICATE_VERIFY_FAILED"):
        httpx.get(f"{tls.url}/healthz")  # the system's CAs alone do not trust the self-signed certificate


def test_tls_viewer_socket_gets_frames_over_wss(tls, tmp_path):
    with tls.client() as client:
        camera = tls_cameras(client)[1]
    frame = wss_viewer_frame(tls, camera, seq=1)
    assert_matches_reference(frame, render_once(TLS_SCENE, camera, SIZE, tmp_path), "TFRM frame over wss://")


def test_tls_node_on_the_host_joins_over_wss(tls, tmp_path):
    node = [PYTHON, "-m", "node", "--coordinator", f"wss://127.0.0.1:{tls.port}/ws/node", "--token", TOKEN]
    system_cas = ssl.get_default_verify_paths().openssl_cafile
    untrusting = start_process([*node, "--name", "host-untrusting"], env={"SSL_CERT_FILE": system_cas})
    try:
        untrusting.wait_for_line(r"cannot reach coordinator .*certificate verify failed", seconds(60))
    finally:
        untrusting.stop()
    trusting = start_process([*node, "--name", "host-over-wss"], env={"SSL_CERT_FILE": str(tls.trusted)})
    try:
        with tls.client() as client:
            wait_until(lambda: {n["name"] for n in ready_nodes(client)} >= {"host-over-wss"}, seconds(120),
                       "the host's node ready over wss://")
            assert len(stats(client)["nodes"]) == 2, "the untrusting node never joined"
            camera = tls_cameras(client)[2]
            _, frame = fetch_frame(client, client.put("/api/camera", json=camera).raise_for_status().json()["frame"])
            wait_until(lambda: all(n["tiles"] and n["tiles_rendered"] for n in stats(client)["nodes"]),
                       seconds(60), "tiles rendered by both nodes")
            assert_matches_reference(frame, render_once(TLS_SCENE, camera, SIZE, tmp_path), "with a node over wss://")
    finally:
        trusting.stop()


def test_tls_viewer_page_over_https_draws_frames_over_wss(tls, tmp_path):
    sockets: list[str] = []
    accept_proxy_key = f"--ignore-certificate-errors-spki-list={spki_sha256(tls.trusted)}"
    with chromium_context(tmp_path / "chromium-profile", args=[accept_proxy_key]) as context:
        page = context.new_page()
        page.on("websocket", lambda socket: sockets.append(socket.url))
        page.goto(f"{tls.url}/?token={TOKEN}")
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=seconds(60) * 1000, polling=100)
        assert page.evaluate("window.tessera.framesDrawn") > 0
        assert sockets and all(url.startswith(f"wss://127.0.0.1:{tls.port}/ws/view") for url in sockets), sockets
        cookie = next(c for c in context.cookies() if c["name"] == TOKEN_COOKIE)
        assert cookie["secure"] and cookie["httpOnly"], "the token cookie is Secure behind the proxy"


def test_tls_proxy_is_hardened_and_healthy(tls):
    proxy = tls.container()
    assert_hardened(proxy)
    assert run(["docker", "exec", proxy, "id", "-u"]).strip() == "10001", "nginx runs unprivileged"
    wait_until(lambda: health(proxy) == "healthy", seconds(60), "the proxy's healthcheck to pass")


def test_tls_mounted_certificate_is_served_and_verified(tls, tmp_path):
    folder = tmp_path / "certs"
    ca = make_certificates(folder)
    tls.start(folder, ca)
    try:
        cert = (folder / "cert.pem").read_text()
        assert tls.served_certificate() == ssl.PEM_cert_to_DER_cert(cert), "the proxy serves the mounted one"
        assert "certificate from TESSERA_TLS_DIR" in run(["docker", "logs", tls.container()])
        with tls.client() as client:
            camera = orbit(tls_cameras(client)[0], 0.5)
            assert client.get("/api/stats").status_code == 200
        frame = wss_viewer_frame(tls, camera, seq=1)
        assert_matches_reference(frame, render_once(TLS_SCENE, camera, SIZE, tmp_path), "wss://, a CA's certificate")
        assert_hardened(tls.container())
    finally:
        tls.start(tls.no_certificates)
