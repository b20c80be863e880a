"""Fetching scene files a node cannot open itself (issue 19: a node in a container without the
coordinator's scene folder): a ``load_scene`` with ``sha256`` and ``url`` names the bytes and where
to get them, and :class:`SceneFetcher` downloads them once into a cache folder.

The cached file is ``<cache>/<sha256><suffix>`` (the suffix of the scene's own name, which picks its
parser). A download streams into a temporary file beside it, hashed as it comes, and is renamed
into place only when its SHA-256 matches, so a cached name always holds the right bytes and nodes
sharing a cache folder never see half a file; a file already cached is used without a download.
One file holds the whole scene: the coordinator serves a library ``.gltf`` whose buffers and
images are separate files made self-contained (:mod:`tessera.scene.gltf_pack`).

``url`` is an absolute http(s) URL or a path on the coordinator, resolved against the node's
``--coordinator`` URL (ws → http, wss → https). The node's token goes along as ``Authorization:
Bearer TOKEN`` to the coordinator's own origin only, never to another host, nor in the query.
Blocking I/O (urllib): call it from a thread of its own, never the GL thread or the event loop.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import urllib.error
import urllib.request
from pathlib import Path
from urllib.parse import urlsplit

from node.scene.loading import BUILTIN_PREFIX, SUPPORTED_SUFFIXES, ProgressCallback
from node.scene.mesh import SceneError

#: Bytes read from the socket and hashed at a time.
CHUNK_BYTES = 1 << 20
#: Seconds a download may wait on the socket (to connect, or for the next bytes).
DOWNLOAD_TIMEOUT_S = 60.0
#: The cache folder's default: beside the system's other temporary files.
DEFAULT_CACHE_DIR = Path(tempfile.gettempdir()) / "tessera-scenes"


def http_origin(coordinator: str) -> str:
    """``scheme://host[:port]`` over HTTP of the ``ws://`` or ``wss://`` ``coordinator`` URL."""
    parts = urlsplit(coordinator)
    scheme = {"ws": "http", "wss": "https"}.get(parts.scheme, parts.scheme)
    return f"{scheme}://{parts.netloc}"


def resolve_url(url: str, origin: str) -> str:
    """``url`` as an absolute http(s) URL: a path (``/api/…``) is on ``origin`` (:func:`http_origin`)."""
    return origin + url if url.startswith("/") else url


class SceneFetcher:
    """Finds a scene's file for loading, downloading it from the coordinator at ``coordinator``
    (its ws(s) URL) with ``token`` into ``cache_dir`` when the node cannot open it."""

    def __init__(self, coordinator: str, token: str | None = None, cache_dir: Path = DEFAULT_CACHE_DIR) -> None:
        self.origin, self.token, self.cache_dir = http_origin(coordinator), token, cache_dir

    def source(self, spec: str, sha256: str | None, url: str | None, progress: ProgressCallback) -> str:
        """What to load for scene ``spec``: ``spec`` itself when it is built in, can be opened, or
        names no file to fetch (``sha256`` or ``url`` None, or a suffix no parser reads); else the
        cached copy of ``url``, downloaded first if missing. Raises SceneError naming the reason."""
        suffix = Path(spec).suffix.lower()
        if (spec.startswith(BUILTIN_PREFIX) or sha256 is None or url is None or suffix not in SUPPORTED_SUFFIXES
                or Path(spec).is_file()):
            return spec
        cached = self.cache_dir / f"{sha256}{suffix}"
        if not cached.is_file():
            self._download(spec, resolve_url(url, self.origin), sha256, cached, progress)
        return str(cached)

    def _download(self, spec: str, url: str, sha256: str, cached: Path, progress: ProgressCallback) -> None:
        """Stream ``url`` into ``cached`` through a temporary file, renamed there once its digest is ``sha256``."""
        progress(0.0, f"downloading {Path(spec).name} from {url}")
        headers = {}
        if self.token and http_origin(url) == self.origin:
            headers["Authorization"] = f"Bearer {self.token}"
        digest, size, partial = hashlib.sha256(), 0, None
        try:
            self.cache_dir.mkdir(parents=True, exist_ok=True)
            with (tempfile.NamedTemporaryFile(dir=self.cache_dir, prefix=f".{sha256}.", suffix=".part",
                                              delete=False) as partial,
                  urllib.request.urlopen(urllib.request.Request(url, headers=headers),
                                         timeout=DOWNLOAD_TIMEOUT_S) as response):
                while block := response.read(CHUNK_BYTES):
                    digest.update(block)
                    partial.write(block)
                    size += len(block)
            if digest.hexdigest() != sha256:
                raise SceneError(f"{spec}: the {size} bytes downloaded from {url} have sha256 {digest.hexdigest()}, "
                                 f"not {sha256}")
            os.replace(partial.name, cached)
        except urllib.error.HTTPError as exc:
            refused = exc.code in (401, 403) and self.token and not headers
            unsent = " (the token goes to the coordinator's origin only)" if refused else ""
            raise SceneError(f"{spec}: download from {url} failed: HTTP {exc.code} {exc.reason}{unsent}") from None
        except (urllib.error.URLError, OSError) as exc:
            raise SceneError(f"{spec}: download from {url} into {self.cache_dir} failed "
                             f"({getattr(exc, 'reason', None) or exc})") from None
        finally:
            if partial is not None:
                Path(partial.name).unlink(missing_ok=True)
        progress(0.0, f"downloaded {Path(spec).name}: {size / 1e6:.1f} MB")
