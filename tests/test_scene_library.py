"""The scene library without HTTP (server/scene_library.py, server/multipart_file.py): names, what is
listed and served (hidden files, symlinks, traversal), atomic uploads, content hashes, the check of
an upload, the multipart reader, and the flags."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest

from node.scene.builtin import BUILTIN_SCENES
from server.multipart_file import FileField, MultipartRefused
from server.scene_library import (
    BadSceneName,
    NotAScene,
    SceneExists,
    SceneLibrary,
    TooLargeToLoad,
    UnknownScene,
    UnsupportedFormat,
    UploadsUnavailable,
    UploadTooLarge,
    check_scene_file,
)
from server.settings import Settings, load_settings
from server.upload_check import checked_triangles
from tests.conftest import scene_path, seconds
from tests.scene_files_support import TRIANGLE_PLY, triangle_gltf


def make_library(tmp_path: Path, max_upload_bytes: int = 1 << 20) -> SceneLibrary:
    (tmp_path / "library").mkdir(exist_ok=True)
    (tmp_path / "data").mkdir(exist_ok=True)
    return SceneLibrary(tmp_path / "library", tmp_path / "data", max_upload_bytes)


def upload(library: SceneLibrary, filename: str, content: bytes) -> str:
    pending = library.begin_upload(filename)
    try:
        pending.write(content)
        pending.finish()
        check_scene_file(pending.temporary, pending.name)
        return pending.commit().name
    finally:
        pending.close()


def names(library: SceneLibrary) -> list[str]:
    return [entry.name for entry in library.entries()]


def test_built_in_scenes_alone_without_folders():
    library = SceneLibrary(None, None, 1 << 20)
    assert [entry.to_json() for entry in library.entries()] == [
        {"name": f"builtin:{name}", "format": "builtin", "bytes": 0} for name in BUILTIN_SCENES]
    assert library.find("builtin:traffic").spec == "builtin:traffic"
    with pytest.raises(UploadsUnavailable, match="--data-dir"):
        library.begin_upload("a.ply")


def test_library_lists_supported_files_in_sub_folders_and_skips_hidden_ones(tmp_path):
    library = make_library(tmp_path)
    root = tmp_path / "library"
    (root / "scans" / "deep").mkdir(parents=True)
    (root / ".hidden").mkdir()
    for relative in ("a.ply", "B.GLB", "scans/c.obj", "scans/deep/d.stl", "e.gltf", ".f.ply", ".hidden/g.ply",
                     "notes.txt", "h.ply.bak"):
        (root / relative).write_bytes(TRIANGLE_PLY)
    assert names(library) == [*(f"builtin:{name}" for name in BUILTIN_SCENES), "library/B.GLB", "library/a.ply",
                              "library/e.gltf", "library/scans/c.obj", "library/scans/deep/d.stl"]
    entry = library.find("library/scans/deep/d.stl")
    assert (entry.format, entry.bytes, entry.spec) == ("stl", len(TRIANGLE_PLY), str(root / "scans/deep/d.stl"))
    assert library.find("library/B.GLB").format == "glb"


def test_symlinks_that_leave_the_folder_are_neither_listed_nor_served(tmp_path):
    library = make_library(tmp_path)
    root = tmp_path / "library"
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.ply").write_bytes(TRIANGLE_PLY)
    (root / "real.ply").write_bytes(TRIANGLE_PLY)
    (root / "inside.ply").symlink_to(root / "real.ply")
    (root / "out.ply").symlink_to(outside / "secret.ply")
    (root / "linked").symlink_to(outside, target_is_directory=True)
    (root / "up").symlink_to(root, target_is_directory=True)
    assert [name for name in names(library) if name.startswith("library/")] == ["library/inside.ply",
                                                                                 "library/real.ply"]
    for name in ("library/out.ply", "library/linked/secret.ply", "library/up/real.ply"):
        with pytest.raises(UnknownScene):
            library.find(name)


@pytest.mark.parametrize("name", [
    "library/../outside/secret.ply", "library/./real.ply", "library//real.ply", "library/real.ply/",
    "library/sub/../real.ply", "library/%2e%2e/outside/secret.ply", "library/..\\outside\\secret.ply",
    str(Path("/etc/passwd")), "/library/real.ply", "library/", "library", "", "upload/../library/real.ply",
    "upload/sub/a.ply", "upload/.upload-0123456789abcdef-a.ply", "builtin:nope", "builtin:", "real.ply",
    "library/real.ply\x00.txt", "LIBRARY/real.ply",
])
def test_names_that_escape_or_do_not_exist_are_unknown(tmp_path, name):
    library = make_library(tmp_path)
    (tmp_path / "outside").mkdir()
    (tmp_path / "outside" / "secret.ply").write_bytes(TRIANGLE_PLY)
    (tmp_path / "library" / "real.ply").write_bytes(TRIANGLE_PLY)
    (tmp_path / "library" / "sub").mkdir()
    library.find("library/real.ply")
    with pytest.raises(UnknownScene):
        library.find(name)


def test_an_upload_is_listed_under_its_file_name_with_its_hash(tmp_path):
    library = make_library(tmp_path)
    assert upload(library, "tri.ply", TRIANGLE_PLY) == "upload/tri.ply"
    entry = library.find("upload/tri.ply")
    assert (entry.format, entry.bytes) == ("ply", len(TRIANGLE_PLY))
    assert entry.path == (tmp_path / "data" / "scenes" / "tri.ply").resolve()
    assert entry.path.read_bytes() == TRIANGLE_PLY
    assert library.content_hash(entry) == hashlib.sha256(TRIANGLE_PLY).hexdigest()
    assert names(library)[-1] == "upload/tri.ply"
    assert names(SceneLibrary(None, tmp_path / "data", 1 << 20))[-1] == "upload/tri.ply"


@pytest.mark.parametrize(("filename", "refusal"), [
    ("", BadSceneName), ("a/b.ply", BadSceneName), ("a\\b.ply", BadSceneName), ("..", BadSceneName),
    ("..ply", BadSceneName), ("a..b.ply", BadSceneName), (".hidden.ply", BadSceneName),
    ("tab\t.ply", BadSceneName), ("nul\x00.ply", BadSceneName), ("del\x7f.ply", BadSceneName),
    ("bidi\u202e.ply", BadSceneName), ("x" * 300 + ".ply", BadSceneName),
    ("a.txt", UnsupportedFormat), ("a", UnsupportedFormat), ("a.ply.exe", UnsupportedFormat),
])
def test_upload_names_refused(tmp_path, filename, refusal):
    library = make_library(tmp_path)
    with pytest.raises(refusal):
        library.begin_upload(filename)
    assert not list((tmp_path / "data").rglob("*.ply*"))


def test_unicode_and_spaces_in_names_are_fine(tmp_path):
    library = make_library(tmp_path)
    assert upload(library, "Schöne Szene (1).PLY", TRIANGLE_PLY) == "upload/Schöne Szene (1).PLY"
    assert library.find("upload/Schöne Szene (1).PLY").format == "ply"


def test_a_taken_name_is_refused_early_and_at_the_commit(tmp_path):
    library = make_library(tmp_path)
    first, second = library.begin_upload("race.ply"), library.begin_upload("race.ply")
    for pending in (first, second):
        pending.write(TRIANGLE_PLY)
        pending.finish()
    first.commit()
    with pytest.raises(SceneExists):
        second.commit()
    second.close()
    with pytest.raises(SceneExists):
        library.begin_upload("race.ply")
    assert sorted(path.name for path in (tmp_path / "data" / "scenes").iterdir()) == ["race.ply"]


def test_an_upload_over_the_limit_stops_and_leaves_nothing(tmp_path):
    library = make_library(tmp_path, max_upload_bytes=1000)
    pending = library.begin_upload("big.ply")
    pending.write(b"x" * 1000)
    with pytest.raises(UploadTooLarge, match="--max-upload-mb"):
        pending.write(b"x")
    pending.close()
    assert list((tmp_path / "data" / "scenes").iterdir()) == []


def test_an_interrupted_upload_is_not_listed_and_is_removed_at_the_next_start(tmp_path):
    library = make_library(tmp_path)
    pending = library.begin_upload("crash.ply")
    pending.write(TRIANGLE_PLY)
    pending.file.close()  # the process dies here: its files close, no finish, commit or close()
    leftover = pending.temporary
    assert leftover.exists() and leftover.parent == tmp_path / "data" / "scenes"
    assert not any(name.startswith("upload/") for name in names(library))
    with pytest.raises(UnknownScene):
        library.find("upload/crash.ply")
    with pytest.raises(UnknownScene):
        library.find("upload/" + leftover.name)
    make_library(tmp_path)
    assert not leftover.exists()


def test_the_hash_is_kept_until_the_file_changes(tmp_path):
    library = make_library(tmp_path)
    path = tmp_path / "library" / "a.ply"
    path.write_bytes(TRIANGLE_PLY)
    entry = library.find("library/a.ply")
    assert library.content_hash(entry) == hashlib.sha256(TRIANGLE_PLY).hexdigest()
    stat = path.stat()
    path.write_bytes(b"y" * len(TRIANGLE_PLY))  # same size: the modification time tells
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert library.content_hash(entry) == hashlib.sha256(TRIANGLE_PLY).hexdigest(), "read once"
    restarted = make_library(tmp_path)   # a coordinator started again over the same data folder
    assert restarted.content_hash(entry) == hashlib.sha256(TRIANGLE_PLY).hexdigest(), "not read after a restart"
    assert SceneLibrary(tmp_path / "library", None, 1 << 20).content_hash(entry) == \
        hashlib.sha256(b"y" * len(TRIANGLE_PLY)).hexdigest(), "without a data folder, read"
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000))
    assert library.content_hash(entry) == hashlib.sha256(b"y" * len(TRIANGLE_PLY)).hexdigest()
    assert make_library(tmp_path).content_hash(entry) == hashlib.sha256(b"y" * len(TRIANGLE_PLY)).hexdigest()


def test_the_check_loads_as_a_node_does(tmp_path):
    good, corrupt, points = tmp_path / "good.ply", tmp_path / "corrupt.ply", tmp_path / "points.ply"
    good.write_bytes(TRIANGLE_PLY)
    corrupt.write_bytes(b"ply\nformat nonsense\n")
    points.write_bytes(TRIANGLE_PLY.replace(b"element face 1", b"element face 0").replace(b"3 0 1 2\n", b""))
    assert check_scene_file(good, "upload/good.ply") == 1
    with pytest.raises(NotAScene, match=r"^upload/corrupt.ply: corrupt or unreadable PLY"):
        check_scene_file(corrupt, "upload/corrupt.ply")
    assert check_scene_file(points, "upload/points.ply") == 0      # vertices without faces: a point cloud (issue 36)


def test_an_uploaded_gltf_must_carry_its_buffers_and_images(tmp_path):
    (tmp_path / "secret.bin").write_bytes(b"\0" * 36)
    cases = {"inline.gltf": triangle_gltf(), "buffer.gltf": triangle_gltf(buffer_uri="secret.bin"),
             "image.gltf": triangle_gltf(image_uri="../../etc/hostname.png")}
    for name, content in cases.items():
        (tmp_path / name).write_bytes(content)
    assert check_scene_file(tmp_path / "inline.gltf", "upload/inline.gltf") == 1
    with pytest.raises(NotAScene, match=r"buffer 'secret\.bin' is a separate file"):
        check_scene_file(tmp_path / "buffer.gltf", "upload/buffer.gltf")
    with pytest.raises(NotAScene, match=r"image '\.\./\.\./etc/hostname\.png' is a separate file"):
        check_scene_file(tmp_path / "image.gltf", "upload/image.gltf")


def test_the_coordinator_checks_in_a_child_process_with_capped_memory(tmp_path):
    corrupt = tmp_path / "corrupt.ply"
    corrupt.write_bytes(b"ply\nformat nonsense\n")
    bunny = scene_path("bunny/bun_zipper.ply")
    assert checked_triangles(bunny, "upload/bunny.ply", Settings().upload_check_memory_mb, seconds(60)) == 69451
    with pytest.raises(NotAScene, match=r"^upload/corrupt.ply: corrupt or unreadable PLY"):
        checked_triangles(corrupt, "upload/corrupt.ply", 4096, seconds(60))
    # 64 MiB of address space is less than the interpreter and its libraries take: loading fails at once.
    with pytest.raises(TooLargeToLoad, match=r"^'upload/bunny.ply' needs more than 64 MiB to load "
                                             r"\(--upload-check-memory-mb\)$"):
        checked_triangles(bunny, "upload/bunny.ply", 64, seconds(60))
    with pytest.raises(NotAScene, match=r"^'upload/bunny.ply' took over 0.01 s to load$"):
        checked_triangles(bunny, "upload/bunny.ply", 4096, 0.01)


def multipart(*parts: tuple[str, str | None, bytes], boundary: str = "b0undary") -> bytes:
    body = b""
    for field, filename, content in parts:
        disposition = f'form-data; name="{field}"' + ("" if filename is None else f'; filename="{filename}"')
        body += f"--{boundary}\r\nContent-Disposition: {disposition}\r\n\r\n".encode() + content + b"\r\n"
    return body + f"--{boundary}--\r\n".encode()


def read_field(body: bytes, chunk: int, content_type: str = "multipart/form-data; boundary=b0undary"
               ) -> tuple[str | None, bytes]:
    form = FileField(content_type, "file")
    data = b"".join(piece for start in range(0, len(body), chunk) for piece in form.feed(body[start:start + chunk]))
    form.finish()
    return form.filename, data


@pytest.mark.parametrize("chunk", [1, 7, 1 << 16])
def test_the_file_field_is_read_in_any_chunks_and_other_fields_are_skipped(chunk):
    content = bytes(range(256)) * 40 + b"\r\n--b0undar"
    body = multipart(("note", None, b"hello"), ("file", "scan.ply", content), ("other", "x.ply", b"nope"))
    assert read_field(body, chunk) == ("scan.ply", content)


def test_a_utf8_file_name_survives():
    body = multipart(("file", "Szene ß.ply", b"abc"))
    assert read_field(body, 5) == ("Szene ß.ply", b"abc")


@pytest.mark.parametrize(("content_type", "body", "reason"), [
    ("application/octet-stream", b"abc", "multipart/form-data"),
    ("multipart/form-data", b"abc", "multipart/form-data"),
    ("multipart/form-data; boundary=b0undary", multipart(("other", "a.ply", b"abc")), "no complete file"),
    ("multipart/form-data; boundary=b0undary", multipart(("file", None, b"abc")), "no filename"),
    ("multipart/form-data; boundary=b0undary", multipart(("file", "a.ply", b"1"), ("file", "b.ply", b"2")),
     "one file per upload"),
    ("multipart/form-data; boundary=b0undary", multipart(("file", "a.ply", b"abc"))[:-30], "no complete file"),
    ("multipart/form-data; boundary=b0undary",
     multipart(("file", "a.ply", b"abc")).replace(b"a.ply", "ä.ply".encode("latin-1")), "not UTF-8"),
])
def test_bodies_without_one_whole_file_field_are_refused(content_type, body, reason):
    with pytest.raises(MultipartRefused, match=reason):
        read_field(body, 1 << 16, content_type)


def test_flags_and_environment_variables(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    settings = load_settings(["--scenes-dir", str(tmp_path), "--max-upload-mb", "64"],
                             {"TESSERA_DATA_DIR": str(tmp_path), "TESSERA_UPLOAD_CHECK_MEMORY_MB": "1024"})
    assert (settings.scenes_dir, settings.data_dir, settings.max_upload_mb) == (tmp_path, tmp_path, 64)
    assert settings.upload_check_memory_mb == 1024 and settings.uploads_home == tmp_path
    assert load_settings(["--upload-check-memory-mb", "300"], {}).upload_check_memory_mb == 300
    assert load_settings(["--data-dir", "none"], {}) == Settings()
    assert (Settings().scenes_dir, Settings().data_dir, Settings().max_upload_mb) == (None, None, 512)
    assert Settings().upload_check_memory_mb == 4096 and Settings().uploads_home is None


def test_without_flags_uploads_go_to_the_users_data_folder_and_the_library_is_dot_scenes(tmp_path, monkeypatch):
    """Issue 38: a coordinator started with no flags has uploads on, in XDG_DATA_HOME/tessera (sessions
    are kept only with --data-dir), and shows ./scenes when the folder it starts from has one."""
    monkeypatch.chdir(tmp_path)
    plain = load_settings([], {"XDG_DATA_HOME": str(tmp_path / "xdg")})
    assert plain.uploads_home == tmp_path / "xdg" / "tessera" and plain.data_dir is None
    assert plain.scenes_dir is None, "no ./scenes here"
    assert load_settings([], {"HOME": "/home/someone"}).uploads_home == Path("/home/someone/.local/share/tessera")
    (tmp_path / "scenes").mkdir()
    assert load_settings([], {}).scenes_dir == tmp_path / "scenes"
    (tmp_path / "other").mkdir()
    assert load_settings(["--scenes-dir", str(tmp_path / "other")], {}).scenes_dir == tmp_path / "other"
    off = load_settings([], {"TESSERA_DATA_DIR": "none"})
    assert off.uploads_home is None and off.data_dir is None


@pytest.mark.parametrize(("argv", "fragment"), [
    (["--scenes-dir", "/nonexistent/scenes"], "must be an existing folder"),
    (["--data-dir", __file__], "must be an existing folder"),
    (["--max-upload-mb", "0"], "must be at least 1"),
    (["--max-upload-mb", "lots"], "must be a whole number"),
    (["--upload-check-memory-mb", "0"], "must be at least 1"),
])
def test_bad_flags_exit_with_a_message(argv, fragment, capsys):
    with pytest.raises(SystemExit):
        load_settings(argv, {})
    assert fragment in capsys.readouterr().err
