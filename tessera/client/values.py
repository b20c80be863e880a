"""The values the client hands back (scene and session summaries) and the camera JSON it sends."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from tessera.client.errors import TesseraError
from tessera.geometry import Camera


@dataclass(frozen=True)
class SceneInfo:
    """A scene of the library: ``name`` (``builtin:NAME``, ``library/PATH``, ``upload/FILE``),
    ``format`` (``builtin`` or the file suffix) and ``bytes``."""

    name: str
    format: str
    bytes: int


@dataclass(frozen=True)
class SessionInfo:
    """An open session as ``GET /api/sessions`` lists it: ``id``, ``scene``, ``size`` (w, h px),
    ``viewers``, ``fps``, ``latency_ms``, ``state`` (``loading``, ``ready``, ``error``) and the rest
    of the summary in ``summary``."""

    id: str
    scene: str
    size: tuple[int, int]
    viewers: int
    fps: float
    latency_ms: float
    state: str
    summary: dict[str, Any]

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> SessionInfo:
        return cls(str(data["id"]), str(data["scene"]), (int(data["size"][0]), int(data["size"][1])),
                   int(data.get("viewers", 0)), float(data.get("fps", 0.0)), float(data.get("latency_ms", 0.0)),
                   str(data.get("state", "")), data)


def camera_json(camera: Camera | dict[str, Any]) -> dict[str, Any]:
    """Camera JSON of a :class:`Camera` or a dict (checked: TesseraError for a camera that cannot be)."""
    try:
        return (camera if isinstance(camera, Camera) else Camera.from_json(camera)).to_json()
    except ValueError as exc:
        raise TesseraError(f"not a camera: {exc}") from None
