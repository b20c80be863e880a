"""``pip install`` as a new user meets it (issue 38): the wheel built from the repository, installed
into a fresh virtual environment outside the checkout, gives ``tessera-server`` and ``tessera-node``
that work from any folder: the viewer page and its scripts are served, local nodes render a frame,
``tessera-node --render-once`` writes one. Without flags the coordinator takes uploads into the
user's data folder and offers the folder's ``scenes/`` as its library, and says so at start. The
folder they run in holds decoy ``node`` and ``server`` packages (a user's own code, or another
distribution's): local nodes still import Tessera's. Dependencies come from PyPI (about 30 s on the
2-core CI machine)."""

from __future__ import annotations

import io
import os
import shutil
import subprocess
import zipfile
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image

from bench.processes import PYTHON, REPO, LoggedProcess
from tests.conftest import seconds
from tests.integration_support import wait_until
from tests.scene_files_support import TRIANGLE_PLY

pytestmark = [pytest.mark.integration, pytest.mark.gl, pytest.mark.timeout(900)]

#: What a wheel is built from: the files a fresh clone has that the build reads.
SOURCES = ("pyproject.toml", "README.md", "tessera", "server", "node", "web")
#: A package in the folder the commands run in, which must never be imported in place of Tessera's.
DECOY = 'raise SystemExit("imported the working folder\'s {name} package, not Tessera\'s")\n'
SIZE = (160, 120)


def run(args: list[str], timeout: float, **kwargs) -> subprocess.CompletedProcess:
    result = subprocess.run(args, capture_output=True, text=True, timeout=seconds(timeout), check=False, **kwargs)
    assert result.returncode == 0, f"{' '.join(args)} exited {result.returncode}:\n{result.stdout}\n{result.stderr}"
    return result


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel ``pip wheel .`` builds from a copy of the repository's sources."""
    root = tmp_path_factory.mktemp("wheel")
    source = root / "source"
    for name in SOURCES:
        origin = REPO / name
        if origin.is_dir():
            shutil.copytree(origin, source / name, symlinks=True, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            source.mkdir(exist_ok=True)
            shutil.copy2(origin, source / name)
    run([PYTHON, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(root / "dist"), str(source)], 300)
    (built,) = (root / "dist").glob("tessera-*.whl")
    return built


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> Iterator[dict[str, str]]:
    """A fresh virtual environment with the wheel installed; the environment its commands run in
    (its bin first on PATH, no PYTHONPATH, the user's data folder in a temporary XDG_DATA_HOME)."""
    root = tmp_path_factory.mktemp("venv")
    venv = root / "venv"
    run([PYTHON, "-m", "venv", "--without-pip", str(venv)], 120)
    run([PYTHON, "-m", "pip", "--python", str(venv / "bin" / "python"), "install", "-q", "--no-compile", str(wheel)],
        600)
    environ = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH", "VIRTUAL_ENV")}
    environ["PATH"] = os.pathsep.join([str(venv / "bin"), *(entry for entry in environ.get("PATH", "").split(os.pathsep)
                                                             if Path(entry) != Path(PYTHON).parent)])
    environ["XDG_DATA_HOME"] = str(root / "data-home")
    yield environ


@pytest.fixture
def user_folder(tmp_path) -> Path:
    """A folder of a user's, outside the checkout, holding decoy ``node`` and ``server`` packages and
    a ``scenes`` folder with one scene."""
    folder = tmp_path / "work"
    for name in ("node", "server"):
        (folder / name).mkdir(parents=True)
        (folder / name / "__init__.py").write_text(DECOY.format(name=name))
    (folder / "scenes").mkdir()
    (folder / "scenes" / "triangle.ply").write_bytes(TRIANGLE_PLY)
    return folder


def test_the_wheel_holds_the_viewer_and_only_tesseras_packages(wheel):
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
    top_level = {name.split("/")[0] for name in names if not name.split("/")[0].endswith(".dist-info")}
    assert top_level == {"tessera", "server", "node"}, "bench/ and tests/ need a checkout; nothing else is ours"
    viewer = {name.removeprefix("server/viewer/") for name in names if name.startswith("server/viewer/")}
    assert {path.name for path in (REPO / "web").iterdir() if path.is_file()} <= viewer
    assert {"tessera/client/widget.js", "tessera/client/widget.css"} <= set(names), "the notebook view's front end"


def test_installed_commands_serve_the_viewer_and_render_from_any_folder(installed, user_folder, tmp_path):
    bin_dir = Path(installed["PATH"].split(os.pathsep)[0])
    for command in ("tessera-server", "tessera-node"):
        helped = run([str(bin_dir / command), "--help"], 60, cwd=user_folder, env=installed)
        assert helped.stdout.startswith(f"usage: {command} "), helped.stdout[:200]
    # The notebook view's front end is made of the viewer's modules, found in the installed package.
    run([str(bin_dir / "python"), "-c", "from tessera.client.widget_bundle import widget_module; "
         "assert 'const module_compositor' in widget_module()"], 60, cwd=user_folder, env=installed)

    out = tmp_path / "once.png"
    run([str(bin_dir / "tessera-node"), "--render-once", str(out), "--scene", "builtin:spheres",
         "--size", f"{SIZE[0]}x{SIZE[1]}"], 180, cwd=user_folder, env=installed)
    with Image.open(out) as image:
        assert image.size == SIZE

    server = LoggedProcess([str(bin_dir / "tessera-server"), "--port", "0", "--local-nodes", "1", "--scene",
                            "builtin:spheres", "--size", f"{SIZE[0]}x{SIZE[1]}"], label="tessera-server",
                           cwd=user_folder, environ=installed, new_session=True, stop_timeout=seconds(20))
    try:
        url = server.wait_for_line(r"Tessera serving on (http://\S+)", seconds(60)).group(1).rstrip("/")
        uploads = Path(installed["XDG_DATA_HOME"]) / "tessera" / "scenes"
        server.wait_for_line(rf"scene library: {user_folder / 'scenes'}$", seconds(10))
        server.wait_for_line(rf"uploads: {uploads} ", seconds(10))
        with httpx.Client(base_url=url, timeout=seconds(30)) as client:
            page = client.get("/")
            assert page.status_code == 200 and "<title>Tessera viewer</title>" in page.text
            for script in ("web/viewer.js", "web/style.css"):
                assert script in page.text and client.get(f"/{script}").status_code == 200, script
            wait_until(lambda: [n for n in client.get("/api/stats").json()["nodes"] if n["state"] == "ready"],
                       seconds(120), "the local node to be ready", interval=0.5)
            frame = client.get("/api/frame.png", params={"after": 1}, timeout=seconds(120))
            assert frame.status_code == 200, frame.text
            image = np.asarray(Image.open(io.BytesIO(frame.content)).convert("RGB"))
            assert image.shape == (SIZE[1], SIZE[0], 3) and len(np.unique(image.reshape(-1, 3), axis=0)) > 8
            assert "library/triangle.ply" in {scene["name"] for scene in client.get("/api/scenes").json()}
            uploaded = client.post("/api/scenes", files={"file": ("mine.ply", TRIANGLE_PLY)})
            assert uploaded.status_code == 201, uploaded.text
            assert (uploads / "mine.ply").read_bytes() == TRIANGLE_PLY
    finally:
        server.stop()
    assert "working folder" not in server.output(), server.output()
