"""The scene library over HTTP: ``GET /api/scenes``, ``GET /api/scenes/{name}/file`` and ``POST
/api/scenes``, in process with FastAPI's ``TestClient``, and once through a real ``python -m server``
(an upload over the limit is cut off while it arrives)."""

from __future__ import annotations

import contextlib
import hashlib
import select
import shutil
import socket
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlsplit

import httpx
import pytest
from fastapi.testclient import TestClient

from node.scene.builtin import BUILTIN_SCENES
from node.scene.loading import load_scene
from server.app import create_app
from server.settings import Settings
from tests.conftest import scene_path, seconds
from tests.scene_files_support import TRIANGLE_PLY, triangle_gltf

pytestmark = pytest.mark.timeout(seconds(120))
BUNNY = "bunny/bun_zipper.ply"
TOKEN = "s3cret"


def settings(tmp_path: Path, **overrides) -> Settings:
    (tmp_path / "library").mkdir(exist_ok=True)
    (tmp_path / "data").mkdir(exist_ok=True)
    values = {"scene": "builtin:spheres", "size": (64, 48), "scenes_dir": tmp_path / "library",
              "data_dir": tmp_path / "data", **overrides}
    return Settings(**values)


@pytest.fixture
def client(tmp_path) -> Iterator[TestClient]:
    with TestClient(create_app(settings(tmp_path))) as client:
        yield client


def post(client: TestClient, filename: str, content: bytes, **kwargs) -> httpx.Response:
    return client.post("/api/scenes", files={"file": (filename, content)}, **kwargs)


def listed(client: TestClient, **kwargs) -> dict[str, dict]:
    answer = client.get("/api/scenes", **kwargs)
    assert answer.status_code == 200, answer.text
    return {entry["name"]: entry for entry in answer.json()}


def test_the_list_holds_built_in_library_and_uploaded_scenes(client, tmp_path):
    bunny = scene_path(BUNNY)
    (tmp_path / "library" / "scans").mkdir()
    shutil.copy(bunny, tmp_path / "library" / "scans" / bunny.name)
    assert post(client, "tri.ply", TRIANGLE_PLY).status_code == 201
    assert client.get("/api/scenes").json() == [
        *({"name": f"builtin:{name}", "format": "builtin", "bytes": 0} for name in BUILTIN_SCENES),
        {"name": "library/scans/bun_zipper.ply", "format": "ply", "bytes": bunny.stat().st_size},
        {"name": "upload/tri.ply", "format": "ply", "bytes": len(TRIANGLE_PLY)},
    ]


def test_an_upload_is_listed_and_served_byte_for_byte(client):
    content = scene_path(BUNNY).read_bytes()
    answer = post(client, "bunny.ply", content)
    assert answer.status_code == 201, answer.text
    sha256 = hashlib.sha256(content).hexdigest()
    assert answer.json() == {"name": "upload/bunny.ply", "sha256": sha256, "bytes": len(content), "triangles": 69451}
    assert listed(client)["upload/bunny.ply"] == {"name": "upload/bunny.ply", "format": "ply", "bytes": len(content)}
    served = client.get("/api/scenes/upload/bunny.ply/file")
    assert served.status_code == 200
    assert served.content == content
    assert served.headers["x-sha256"] == sha256


def test_a_library_file_is_served_with_its_hash(client, tmp_path):
    (tmp_path / "library" / "sub").mkdir()
    (tmp_path / "library" / "sub" / "tri.gltf").write_bytes(triangle_gltf())
    served = client.get("/api/scenes/library/sub/tri.gltf/file")
    assert served.status_code == 200
    assert served.content == triangle_gltf()
    assert served.headers["x-sha256"] == hashlib.sha256(triangle_gltf()).hexdigest()


def test_a_library_gltf_with_separate_files_is_served_as_one_file_that_loads_alone(client, tmp_path):
    truck = scene_path("gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf")
    shutil.copytree(truck.parent, tmp_path / "library" / "truck")
    served = client.get("/api/scenes/library/truck/CesiumMilkTruck.gltf/file")
    assert served.status_code == 200, served.text
    assert served.headers["x-sha256"] == hashlib.sha256(served.content).hexdigest()
    alone = tmp_path / "alone" / "truck.gltf"
    alone.parent.mkdir()
    alone.write_bytes(served.content)
    assert load_scene(str(alone)).triangle_count == load_scene(str(truck)).triangle_count > 0
    (tmp_path / "outside.bin").write_bytes(b"\0" * 36)
    escaping = triangle_gltf(buffer_uri="../../outside.bin")
    (tmp_path / "library" / "sub").mkdir()
    (tmp_path / "library" / "sub" / "out.gltf").write_bytes(escaping)
    served = client.get("/api/scenes/library/sub/out.gltf/file")
    assert served.status_code == 200 and served.content == escaping, "a file outside the library is never inlined"


@pytest.mark.parametrize(("filename", "content", "status", "reason"), [
    ("notes.txt", TRIANGLE_PLY, 415, "unsupported file type"),
    ("../tri.ply", TRIANGLE_PLY, 422, "with '/' or '\\'"),
    ("a\\tri.ply", TRIANGLE_PLY, 422, "with '/' or '\\'"),
    ("a..tri.ply", TRIANGLE_PLY, 422, "'..'"),
    (".hidden.ply", TRIANGLE_PLY, 422, "hidden"),
    ("junk.ply", b"not a mesh at all", 422, "upload/junk.ply: corrupt or unreadable PLY"),
    ("empty.stl", b"", 422, "upload/empty.stl"),
    ("outside.gltf", triangle_gltf(buffer_uri="../../library/x.bin"), 422, "is a separate file"),
])
def test_bad_uploads_are_refused_with_the_reason_and_leave_nothing(client, tmp_path, filename, content, status,
                                                                   reason):
    answer = post(client, filename, content)
    assert answer.status_code == status, answer.text
    assert reason in answer.json()["detail"]
    assert not [name for name in listed(client) if name.startswith("upload/")]
    assert list((tmp_path / "data").rglob("*.*")) == []


@pytest.mark.parametrize(("filename", "reason"), [("ctl\x01.ply", "control"), ("", "empty"), ("a/b.ply", "'/'")])
def test_names_httpx_would_rewrite_are_refused(client, filename, reason):
    """Sent as written: httpx percent-encodes control characters in file names and leaves out empty ones."""
    body = (b'--b0undary\r\nContent-Disposition: form-data; name="file"; filename="' + filename.encode() +
            b'"\r\n\r\n' + TRIANGLE_PLY + b"\r\n--b0undary--\r\n")
    answer = client.post("/api/scenes", content=body,
                         headers={"content-type": "multipart/form-data; boundary=b0undary"})
    assert answer.status_code == 422, answer.text
    assert reason in answer.json()["detail"]


def test_a_name_taken_is_409_and_the_first_upload_stays(client):
    assert post(client, "tri.ply", TRIANGLE_PLY).status_code == 201
    answer = post(client, "tri.ply", TRIANGLE_PLY + b"\n")
    assert answer.status_code == 409
    assert "exists already" in answer.json()["detail"]
    assert client.get("/api/scenes/upload/tri.ply/file").content == TRIANGLE_PLY


def test_malformed_forms_are_422(client):
    assert client.post("/api/scenes", content=TRIANGLE_PLY).status_code == 422
    assert client.post("/api/scenes", files={"scene": ("tri.ply", TRIANGLE_PLY)}).status_code == 422
    answer = client.post("/api/scenes", data={"file": "tri.ply"})
    assert answer.status_code == 422
    assert "multipart" in answer.json()["detail"]


def test_uploads_over_the_limit_are_413(tmp_path):
    with TestClient(create_app(settings(tmp_path, max_upload_mb=1))) as client:
        answer = post(client, "big.ply", TRIANGLE_PLY + b"0 0 0\n" * 200_000)
        assert answer.status_code == 413
        assert "over the limit of 1 MiB (--max-upload-mb)" in answer.json()["detail"]
        declared = client.post("/api/scenes", content=b"x", headers={
            "content-type": "multipart/form-data; boundary=x", "content-length": str(2 << 20)})
        assert declared.status_code == 413
        assert list((tmp_path / "data").rglob("*.*")) == []


def test_an_upload_that_needs_more_memory_to_load_than_the_cap_is_413_and_the_rest_goes_on(tmp_path):
    """The check loads the file in a child process: over --upload-check-memory-mb it is refused and
    the coordinator (this process) serves on, takes the file once it may use more, and keeps nothing
    of the refused one."""
    bunny = scene_path(BUNNY).read_bytes()
    with TestClient(create_app(settings(tmp_path, upload_check_memory_mb=64))) as client:
        answer = post(client, "bunny.ply", bunny)
        assert answer.status_code == 413, answer.text
        assert answer.json()["detail"] == "'upload/bunny.ply' needs more than 64 MiB to load (--upload-check-memory-mb)"
        assert "upload/bunny.ply" not in listed(client)
        assert list((tmp_path / "data").rglob("*.*")) == []
        assert client.get("/api/camera").status_code == 200
    with TestClient(create_app(settings(tmp_path))) as client:
        answer = post(client, "bunny.ply", bunny)
        assert answer.status_code == 201, answer.text
        assert answer.json()["triangles"] == 69451


def test_without_a_data_dir_uploads_are_503_and_the_library_still_lists(tmp_path):
    with TestClient(create_app(settings(tmp_path, data_dir=None))) as client:
        answer = post(client, "tri.ply", TRIANGLE_PLY)
        assert answer.status_code == 503
        assert "--data-dir" in answer.json()["detail"]
        assert set(listed(client)) == {f"builtin:{name}" for name in BUILTIN_SCENES}
        library = client.get("/api/library").json()
        assert library["uploads"] is False and library["uploads_off"] == answer.json()["detail"]


def test_the_library_says_what_the_picker_offers_and_how_to_add_scenes(client, tmp_path):
    """Issue 38: the panel offers what the server allows, and says how to fill an empty library."""
    empty = client.get("/api/library").json()
    assert empty["folder"] == str((tmp_path / "library").resolve()) and empty["library_scenes"] == 0
    assert empty["folder"] in empty["library_hint"] and "put GLB" in empty["library_hint"]
    assert (empty["uploads"], empty["uploads_off"], empty["max_upload_mb"]) == (True, None, 512)
    assert {"glb", "gltf", "ply"} <= set(empty["formats"])
    shutil.copy(scene_path(BUNNY), tmp_path / "library" / "bunny.ply")
    assert client.get("/api/library").json()["library_scenes"] == 1
    assert client.get("/api/library").json()["library_hint"] is None
    with TestClient(create_app(settings(tmp_path, scenes_dir=None))) as bare:
        assert "--scenes-dir" in bare.get("/api/library").json()["library_hint"]


@pytest.mark.parametrize("path", [
    "/api/scenes/library/..%2F..%2Foutside%2Fsecret.ply/file",
    "/api/scenes/library/%2E%2E/%2E%2E/outside/secret.ply/file",
    "/api/scenes/upload/%2E%2E%2F%2E%2E%2Foutside%2Fsecret.ply/file",
    "/api/scenes/library%2F..%2F..%2Foutside%2Fsecret.ply/file",
    "/api/scenes/library/%2Fetc%2Fpasswd/file",
    "/api/scenes/%2Fetc%2Fpasswd/file",
    "/api/scenes/library/out.ply/file",
    "/api/scenes/library/linked/secret.ply/file",
    "/api/scenes/library/..%5Coutside%5Csecret.ply/file",
    "/api/scenes/builtin:cluster/file",
    "/api/scenes/library/missing.ply/file",
])
def test_nothing_outside_the_folders_is_served(client, tmp_path, path):
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.ply").write_bytes(TRIANGLE_PLY)
    (tmp_path / "library" / "out.ply").symlink_to(outside / "secret.ply")
    (tmp_path / "library" / "linked").symlink_to(outside, target_is_directory=True)
    answer = client.get(path)
    assert answer.status_code == 404, answer.text
    assert TRIANGLE_PLY not in answer.content


def test_the_token_guards_every_scene_route(tmp_path):
    with TestClient(create_app(settings(tmp_path, token=TOKEN))) as client:
        bearer = {"Authorization": f"Bearer {TOKEN}"}
        assert client.get("/api/scenes").status_code == 401
        assert post(client, "tri.ply", TRIANGLE_PLY).status_code == 401
        assert post(client, "tri.ply", TRIANGLE_PLY, headers={"Authorization": "Bearer wrong"}).status_code == 401
        assert not [name for name in listed(client, headers=bearer) if name.startswith("upload/")]
        assert post(client, "tri.ply", TRIANGLE_PLY, headers=bearer).status_code == 201
        assert client.get("/api/scenes/upload/tri.ply/file").status_code == 401
        served = client.get("/api/scenes/upload/tri.ply/file", headers=bearer)
        assert (served.status_code, served.content) == (200, TRIANGLE_PLY)


def test_a_page_of_another_origin_cannot_upload(client):
    answer = post(client, "tri.ply", TRIANGLE_PLY, headers={"Origin": "https://elsewhere.example"})
    assert answer.status_code == 403
    assert "upload/tri.ply" not in listed(client)


def send_until_answered(sock: socket.socket, chunk: bytes, most: int) -> int:
    """Send ``chunk`` (as HTTP chunks) until the server answers or ``most`` bytes went; the bytes sent."""
    sent = 0
    while sent < most and not select.select([sock], [], [], 0)[0]:
        try:
            sock.sendall(b"%x\r\n%s\r\n" % (len(chunk), chunk))
        except OSError:  # the server answered and closed, or stopped reading: the answer is there
            break
        sent += len(chunk)
    return sent


def read_answer(sock: socket.socket) -> bytes:
    """What the server sent until it closed the connection (or reset it)."""
    received = b""
    with contextlib.suppress(ConnectionResetError):
        while chunk := sock.recv(65536):
            received += chunk
    return received


@pytest.mark.integration
def test_a_real_coordinator_takes_an_upload_and_cuts_one_over_the_limit_short(coordinator_factory, tmp_path):
    (tmp_path / "data").mkdir()
    coordinator = coordinator_factory("--scene", "builtin:spheres", "--data-dir", str(tmp_path / "data"),
                                      "--max-upload-mb", "1", "--token", TOKEN)
    bearer = {"Authorization": f"Bearer {TOKEN}"}
    with httpx.Client(base_url=coordinator.url, headers=bearer, timeout=seconds(30)) as http:
        answer = http.post("/api/scenes", files={"file": ("tri.ply", TRIANGLE_PLY)})
        assert answer.status_code == 201, answer.text
        # A chunked body (no Content-Length to refuse it by) of up to 64 MiB, sent a chunk at a time:
        # the answer comes once the first MiB is in, and the server reads no further.
        address = urlsplit(coordinator.url)
        with socket.create_connection((address.hostname, address.port), timeout=seconds(10)) as sock:
            sock.sendall(b"POST /api/scenes HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " + TOKEN.encode() +
                         b"\r\nContent-Type: multipart/form-data; boundary=b0undary\r\nTransfer-Encoding: chunked"
                         b"\r\n\r\n")
            part = b'--b0undary\r\nContent-Disposition: form-data; name="file"; filename="big.ply"\r\n\r\n'
            sock.sendall(b"%x\r\n%s\r\n" % (len(part), part))
            sent = send_until_answered(sock, b"0 0 0\n" * 10_000, 64 << 20)
            answer_bytes = read_answer(sock)
        assert answer_bytes.startswith(b"HTTP/1.1 413"), answer_bytes[:200]
        assert b"--max-upload-mb" in answer_bytes
        # What was sent past the first MiB waited in the kernels' socket buffers (4.5 MB on loopback).
        assert sent < 32 << 20, f"{sent} bytes went before the server answered"
        names = [entry["name"] for entry in http.get("/api/scenes").json()]
        assert names[-1] == "upload/tri.ply" and "upload/big.ply" not in names
        assert sorted(path.name for path in (tmp_path / "data" / "scenes").iterdir()) == ["tri.ply"]
