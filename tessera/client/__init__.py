"""The Python client of a Tessera coordinator (issue 33): ``from tessera.client import Tessera``.

It speaks the coordinator's public REST and WebSocket API (httpx, websockets) and imports no
server code. ``Tessera(url, token)`` lists scenes and sessions, uploads files, meshes and arrays,
and opens sessions; a :class:`Session` steers the camera, objects and animation, returns frames as
numpy arrays and shows a live view in Jupyter (:meth:`Session.show`). Every error is one
:class:`TesseraError` carrying the coordinator's reason.
"""

from tessera.client.coordinator import SceneInfo, SessionInfo, Tessera
from tessera.client.errors import TesseraError
from tessera.client.scene_state import Animation, Objects, SceneObject
from tessera.client.session import Session
from tessera.geometry import Camera

__all__ = ["Animation", "Camera", "Objects", "SceneInfo", "SceneObject", "Session", "SessionInfo", "Tessera",
           "TesseraError"]
