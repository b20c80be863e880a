"""Sessions that outlive the coordinator (issue 19): with ``--data-dir``, every session's scene,
size, camera, balancer and scene state (object poses, animation clock) are written to
``DIR/sessions.json`` and read back at start-up, under the same ids and watch keys, so open
viewers reconnect to the session they had. Writes are atomic (a temporary file in the same folder,
flushed to disk, then renamed over the old one): a crash leaves the old file or the new one, never
half of either. A file that does not read is set aside (``sessions.json.bad``) and logged; the
coordinator starts with its default session only."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

log = logging.getLogger("tessera.server")

FILE_NAME = "sessions.json"
#: The folder of each session's last mesh step (issue 33): ``SESSION_ID.tmsh``, a mesh message.
MESH_FOLDER = "meshes"
MESH_SUFFIX = ".tmsh"
#: The format of the file; another one is set aside, not misread.
FORMAT = 1


class SessionStore:
    """``DIR/sessions.json``: a list of session records (plain JSON)."""

    def __init__(self, data_dir: Path) -> None:
        self.path = data_dir / FILE_NAME
        self.meshes = data_dir / MESH_FOLDER

    def load(self) -> list[dict[str, Any]]:
        """The records saved last; [] when there are none or the file does not read."""
        try:
            data = json.loads(self.path.read_text())
            if not isinstance(data, dict) or data.get("format") != FORMAT or not isinstance(data.get("sessions"), list):
                raise ValueError(f"not a format-{FORMAT} sessions file")
            return [record for record in data["sessions"] if isinstance(record, dict)]
        except FileNotFoundError:
            return []
        except (OSError, ValueError) as exc:
            aside = self.path.with_name(FILE_NAME + ".bad")
            log.error("cannot read %s (%s); set aside as %s, starting without the sessions it held", self.path,
                      exc, aside.name)
            self.path.replace(aside)
            return []

    def save(self, records: list[dict[str, Any]]) -> None:
        """Write ``records`` atomically."""
        temporary = self.path.with_name(f".{FILE_NAME}.{os.getpid()}.tmp")
        with temporary.open("w") as file:
            json.dump({"format": FORMAT, "sessions": records}, file)
            file.flush()
            os.fsync(file.fileno())
        temporary.replace(self.path)

    def save_meshes(self, changed: dict[str, bytes], kept: set[str]) -> None:
        """Write each session's mesh of ``changed`` (session id → mesh message) atomically and
        remove those of sessions not in ``kept``."""
        if changed:
            self.meshes.mkdir(exist_ok=True)
        for session_id, data in changed.items():
            temporary = self.meshes / f".{session_id}.{os.getpid()}.tmp"
            with temporary.open("wb") as file:
                file.write(data)
                file.flush()
                os.fsync(file.fileno())
            temporary.replace(self.meshes / f"{session_id}{MESH_SUFFIX}")
        for old in self.meshes.glob(f"*{MESH_SUFFIX}") if self.meshes.is_dir() else ():
            if old.name[:-len(MESH_SUFFIX)] not in kept:
                old.unlink(missing_ok=True)

    def load_mesh(self, session_id: str) -> bytes | None:
        """The mesh message saved for ``session_id`` (None: none)."""
        try:
            return (self.meshes / f"{session_id}{MESH_SUFFIX}").read_bytes()
        except (FileNotFoundError, ValueError):
            return None
