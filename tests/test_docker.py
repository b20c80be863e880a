"""The real deployment: the image from the Dockerfile, run by docker-compose.yml under Compose and
unchanged under Swarm (`docker stack deploy`), with docker-compose.tls.yml's TLS proxy in front.

Builds the images (scripts/docker-base, then `compose build`), starts a coordinator and three
render nodes, checks a composited frame against ``python -m node --render-once`` on the host, the
viewer in headless Chromium, that every container is read-only with no capabilities, a killed node
container, a rejoin, and that `down -v` leaves nothing. Then the TLS proxy: the API, frames, a
``wss://`` viewer socket, a node on the host joining over ``wss://``, the viewer page over https, a
self-signed and a mounted certificate. Without Docker the tests skip, except in CI (CI=true), where
they fail.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass

import httpx
import pytest

from tests.browser_support import DRAWN_FRACTION_JS, chromium_context, unavailable
from tests.conftest import REPO, SCENES, scene_path, seconds
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


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


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
    return command


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
            "TESSERA_PROXY_IMAGE": "", **extra}


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


@pytest.fixture(scope="module")
def deployment(compose) -> Iterator[Deployment]:
    """`compose up -d --scale node=3` with the real bunny from the mounted scenes folder."""
    scene_path(SCENE)
    port = free_port()
    env = deployment_env(port, COMPOSE_PROJECT_NAME=f"tessera-test-{uuid.uuid4().hex[:8]}",
                         TESSERA_SCENES_DIR=str(SCENES), TESSERA_SCENE=f"/scenes/{SCENE}")
    with coordinator_client(port) as client:
        deployment = Deployment([*compose, *COMPOSE_FILES], env, client)
        try:
            deployment.run("up", "-d", "--scale", "node=3")
            wait_serving(client, seconds(120))
            yield deployment
        finally:
            deployment.run("down", "-v", "--remove-orphans", "--timeout", "10")


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
    assert all(node["tiles"] for node in stats(client)["nodes"]), "every container renders part of the frame"
    containers = run(["docker", "ps", "-q", "--filter", f"label=com.docker.compose.project={deployment.project}"])
    wait_until(lambda: all(health(c) == "healthy" for c in containers.split()), seconds(90),
               "every container's healthcheck to pass")


def test_viewer_from_the_host_draws_a_frame(deployment, tmp_path):
    with chromium_context(tmp_path / "chromium-profile") as context:
        page = context.new_page()
        page.goto(f"{deployment.client.base_url}/?token={TOKEN}")
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=seconds(60) * 1000, polling=100)
        assert page.evaluate("window.tessera.framesDrawn") > 0


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
    wait_until(lambda: all(node["tiles"] for node in stats(client)["nodes"]), seconds(60),
               "tiles for all 3 nodes")
    report(request, f"scale back to 3 → rejoined and rendering {time.monotonic() - resumed_at:.2f} s")
    assert_matches_reference(frame, render_once(str(scene_path(SCENE)), cameras[2], SIZE, tmp_path), "rejoined")


def test_down_leaves_nothing_running(deployment):
    label = f"com.docker.compose.project={deployment.project}"
    assert labelled("container", label), "the project should be running before down"
    deployment.run("down", "-v", "--remove-orphans", "--timeout", "10")
    assert labelled("container", label) == []
    assert labelled("network", label) == []


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
    port = free_port()
    env = deployment_env(port)
    label = f"com.docker.stack.namespace={stack}"
    try:
        run(["docker", "stack", "deploy", "--resolve-image", "never", "-c", "docker-compose.yml", stack], env=env)
        with coordinator_client(port) as client:
            wait_serving(client, seconds(120))
            wait_until(lambda: len(ready_nodes(client)) == 3, seconds(180), "3 ready Swarm nodes")
            camera = orbit_cameras(client.get("/api/camera").json()["bounds"], 1)[0]
            _, frame = fetch_frame(client, client.put("/api/camera", json=camera).json()["frame"])
            assert_matches_reference(frame, render_once("builtin:cluster", camera, SIZE, tmp_path), "swarm x3")
    finally:
        run(["docker", "stack", "rm", stack])
        wait_until(lambda: not labelled("container", label) and not labelled("network", label), seconds(120),
                   f"stack {stack} to be removed")
