"""The manual cannot rot: the generated command-line, HTTP and message references against
``--help`` and a running coordinator's ``/openapi.json``; the stats, metrics and panel pages against
what a real coordinator and the viewer page show; the tutorials' commands run against a real
coordinator; README short, and no commit hash or tried-and-reverted story where users read.
(``mkdocs build --strict`` itself runs in scripts/test.)"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from PIL import Image

from bench.processes import PYTHON, REPO
from tests.conftest import Coordinator, scene_path, seconds, start_coordinator
from tests.docs_support import DOCS, code_blocks, docs_reference, generated
from tests.integration_support import wait_rendering

pytestmark = pytest.mark.integration

FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")
#: The pages whose commands the tests run: the tutorials and README.
RUNNABLE = [*sorted((DOCS / "tutorials").glob("*.md")), REPO / "README.md"]
#: A commit hash: 7 to 40 hex digits with a letter and a digit among them.
COMMIT_HASH = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b")
HISTORY_WORDS = re.compile(r"\b(reverted|tried and|taken out|was tried|we tried)\b", re.I)


def help_flags(module: str) -> set[str]:
    """Every long flag ``python -m MODULE --help`` lists as an option (its aliases included)."""
    result = subprocess.run([PYTHON, "-m", module, "--help"], cwd=REPO, capture_output=True, text=True,
                            timeout=seconds(60), check=True)
    options = [line.strip().split("  ", 1)[0] for line in result.stdout.splitlines() if re.match(r"^  {1,4}-", line)]
    return {flag for option in options for flag in FLAG.findall(option)} - {"--help"}


@pytest.mark.parametrize("module", ["server", "node"])
def test_the_command_line_reference_lists_every_flag_of_help(module):
    flags = help_flags(module)
    table = generated("reference/cli.md")
    section = table.split(f"## `python -m {module}`", 1)[1].split("\n## ", 1)[0]
    documented = set(re.findall(r"^\| (`--[^|]+)\|", section, re.M))
    documented_flags = {flag for row in documented for flag in FLAG.findall(row)}
    assert len(flags) > 10
    assert flags == documented_flags, (f"in --help, not in the reference: {sorted(flags - documented_flags)}; "
                                       f"in the reference, not in --help: {sorted(documented_flags - flags)}")


def test_every_variable_of_the_compose_files_is_documented():
    variables = set()
    for path in REPO.glob("docker-compose*.yml"):
        variables |= set(re.findall(r"\b(TESSERA_[A-Z0-9_]+)", path.read_text()))
    page = generated("reference/cli.md")
    missing = sorted(v for v in variables if f"`{v}`" not in page)
    assert not missing, f"variables of the Compose files missing from docs/reference/cli.md: {missing}"


def test_every_message_of_the_catalogue_is_in_the_messages_reference():
    page = generated("reference/messages.md")
    kinds = {cls.kind for cls in docs_reference.all_messages()}
    assert {"hello", "render", "tile_sent", "camera", "stream_offer", "present"} <= kinds
    missing = sorted(kind for kind in kinds if f"| `{kind}` |" not in page)
    assert not missing, f"messages missing from docs/reference/messages.md: {missing}"


def test_every_public_method_of_the_python_client_is_in_its_reference():
    from tessera.client import Session, Tessera

    page = generated("reference/python-client.md")
    for cls in (Tessera, Session):
        public = [name for name in vars(cls) if not name.startswith("_")]
        missing = [name for name in public if f"### `{cls.__name__}.{name}`" not in page]
        assert not missing, f"{cls.__name__} members missing from docs/reference/python-client.md: {missing}"


def test_every_panel_figure_of_the_viewer_is_explained():
    labels = re.findall(r"<dt>([^<]+)</dt>", (REPO / "web" / "index.html").read_text())
    page = (DOCS / "reference" / "viewer.md").read_text()
    assert len(labels) >= 5
    missing = [label for label in labels if f"**{label.replace('&gt;', '>')}**" not in page]
    assert not missing, f"panel figures of web/index.html not explained in docs/reference/viewer.md: {missing}"


def test_readme_is_short_and_says_how_to_run_and_test():
    readme = (REPO / "README.md").read_text()
    assert len(readme.splitlines()) <= 250
    for needed in ("docker compose up", "scripts/docker-base", "--build", "scripts/test",
                   "python -m server --local-nodes 3", "docs/"):
        assert needed in readme, f"README lacks {needed!r}"


@pytest.mark.parametrize("path", [REPO / "README.md", *sorted((DOCS / "tutorials").glob("*.md")),
                                  *sorted((DOCS / "how-to").glob("*.md"))], ids=lambda p: p.name)
def test_no_commit_hash_or_history_where_users_read(path):
    text = path.read_text()
    assert not COMMIT_HASH.findall(text), f"{path.name}: commit hashes {COMMIT_HASH.findall(text)}"
    assert not HISTORY_WORDS.findall(text), f"{path.name}: history belongs in commits: {HISTORY_WORDS.findall(text)}"


# ---- against a real coordinator ------------------------------------------------------------------

@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    """The tutorials' working folder: ``model.glb`` and ``models/model.glb`` (a real glTF scene)."""
    folder = tmp_path_factory.mktemp("tutorial")
    (folder / "models").mkdir()
    (folder / "data").mkdir()
    model = scene_path("gltf_small/Duck.glb")
    shutil.copy(model, folder / "model.glb")
    shutil.copy(model, folder / "models" / "model.glb")
    return folder


@pytest.fixture(scope="module")
def coordinator(workdir) -> Iterator[Coordinator]:
    """The tutorials' coordinator: one local node, small frames, the library and data folders of
    ``workdir``."""
    started = start_coordinator("--local-nodes", "1", "--size", "320x180", "--scenes-dir", str(workdir / "models"),
                                "--data-dir", str(workdir / "data"))
    try:
        with httpx.Client(base_url=started.url, timeout=seconds(60)) as client:
            wait_rendering(client, 1)
        yield started
    finally:
        started.proc.stop()


def test_every_route_of_the_openapi_schema_is_in_the_reference(coordinator):
    schema = httpx.get(f"{coordinator.url}/openapi.json", timeout=seconds(30)).raise_for_status().json()
    page = generated("reference/http-api.md")
    routes = [(method.upper(), path) for path, operations in schema["paths"].items() for method in operations]
    assert len(routes) > 20
    missing = [f"{method} {path}" for method, path in routes if f"`{method} {path}`" not in page]
    assert not missing, f"routes of /openapi.json missing from docs/reference/http-api.md: {missing}"


def test_every_field_of_the_stats_and_every_metric_is_documented(coordinator):
    with httpx.Client(base_url=coordinator.url, timeout=seconds(30)) as client:
        stats = client.get("/api/stats").raise_for_status().json()
        metrics = client.get("/metrics").raise_for_status().text
    page = (DOCS / "reference" / "stats.md").read_text()
    fields = set(stats)
    for nested in ("coordinator_cpu", "scene_state", "still_samples"):
        fields |= set(stats[nested] or {})
    fields |= set(stats["nodes"][0]) | set(stats["sessions"][0])
    missing = sorted(field for field in fields if f"`{field}`" not in page)
    assert not missing, f"/api/stats fields missing from docs/reference/stats.md: {missing}"
    series = {name.removesuffix("_created") for name in re.findall(r"^# HELP (tessera_\w+)", metrics, re.M)}
    assert len(series) > 10
    missing = sorted(name for name in series if f"`{name}" not in page)
    assert not missing, f"/metrics series missing from docs/reference/stats.md: {missing}"


def run_blocks(blocks: list[str], command: list[str], workdir: Path, url: str, suffix: str) -> None:
    """Run ``blocks`` one after the other as one script of ``command`` in ``workdir``, the manual's
    ``http://localhost:8000`` pointing at ``url``; fails with the output and the block that failed."""
    script = workdir / f"tutorial{suffix}"
    marker = "echo '::block {}::'\n" if suffix == ".sh" else "print('::block {}::', flush=True)\n"
    text = "".join(marker.format(i) + block for i, block in enumerate(blocks, 1))
    script.write_text(text.replace("http://localhost:8000", url).replace("localhost:8000", url.split("//", 1)[1]))
    env = {**os.environ, "PATH": f"{Path(PYTHON).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    result = subprocess.run([*command, str(script)], cwd=workdir, env=env, capture_output=True, text=True,
                            timeout=seconds(240), check=False)
    if result.returncode != 0:
        done = re.findall(r"::block (\d+)::", result.stdout)
        failed = blocks[int(done[-1]) - 1] if done else "(before the first block)"
        pytest.fail(f"block {done[-1] if done else '?'} failed (exit {result.returncode}):\n{failed}\n"
                    f"--- stdout\n{result.stdout[-3000:]}\n--- stderr\n{result.stderr[-3000:]}")


@pytest.mark.parametrize("page", RUNNABLE, ids=lambda p: p.stem)
def test_the_tutorials_commands_run_against_a_real_coordinator(page, coordinator, workdir):
    blocks = [block for block in code_blocks(page) if block.not_run is None]
    shell = [block.body for block in blocks if block.lang in ("sh", "bash")]
    python = [block.body for block in blocks if block.lang == "python"]
    unknown = [block.lang for block in blocks if block.lang not in ("sh", "bash", "python", "json", "text")]
    assert not unknown, (f"{page.name}: code blocks the test cannot run: {unknown} "
                         "(mark them <!-- not run by tests: REASON -->)")
    if not shell and not python and page.stem != "index":
        pytest.fail(f"{page.name} has no command the tests run")
    if shell:
        # curl fails on an HTTP error, as a user would notice the error message
        run_blocks([body.replace("curl ", "curl --fail-with-body ") for body in shell],
                   ["bash", "-euo", "pipefail"], workdir, coordinator.url, ".sh")
    if python:
        if importlib.util.find_spec("tessera.client") is None:
            pytest.skip(f"{page.name}: its Python blocks need tessera.client, which is not installed")
        run_blocks(python, [PYTHON], workdir, coordinator.url, ".py")


def test_the_front_page_picture_shows_the_viewer_as_it_is():
    from bench.screenshot import DIGEST_KEY, MADE_KEY, VIEWER_FILES, viewer_digest

    picture = DOCS / "screenshot.png"
    assert picture.stat().st_size < 1 << 20, "docs/screenshot.png over 1 MiB"
    with Image.open(picture) as image:
        assert image.size == (1280, 720)
        made, digest = image.text.get(MADE_KEY), image.text.get(DIGEST_KEY)
    assert made and digest, "docs/screenshot.png was not made by python -m bench.screenshot"
    assert digest == viewer_digest(), (f"{', '.join(VIEWER_FILES)} changed since docs/screenshot.png was made "
                                       f"({made}): run python -m bench.screenshot and commit the picture")
