"""A session's named objects and animation clock from Python: ``session.objects["name"].visible =
False``, ``session.animation.play()`` (``/objects``, ``/animation`` of the session's routes)."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from typing import Any, Protocol
from urllib.parse import quote


class Session(Protocol):
    """What objects and the animation need of a :class:`tessera.client.session.Session`."""

    def call(self, method: str, route: str, **options: Any) -> Any: ...

    def changed(self, answer: dict[str, Any]) -> int: ...

    def wait_ready(self, timeout: float | None = None) -> Session: ...


def described(session: Session) -> dict[str, dict[str, Any]]:
    """Every object of the session's scene as ``GET /objects`` describes it, by name."""
    return {item["name"]: item for item in session.wait_ready().call("GET", "objects")}


class SceneObject:
    """Object ``name`` of a session's scene: ``translation`` [x, y, z], ``rotation`` [qx, qy, qz, qw],
    ``scale`` [sx, sy, sz] (all relative to its parent) and ``visible``; reading one asks the
    coordinator (animation and poses applied), setting one poses it from the next frame."""

    def __init__(self, session: Session, name: str) -> None:
        self.session = session
        self.name = name

    def state(self) -> dict[str, Any]:
        """The object as ``GET /objects`` lists it: pose now, ``bounds``, ``triangles``, ``parent``."""
        return described(self.session)[self.name]

    def pose(self, **fields: Any) -> int:
        """Set any of ``translation``, ``rotation``, ``scale``, ``visible`` at once; returns the
        first frame id that shows it (422 for a bad value: nothing changes)."""
        body = {key: (value if isinstance(value, bool) else [float(v) for v in value]) for key, value in fields.items()}
        return self.session.changed(self.session.call("PUT", f"objects/{quote(self.name, safe='')}", json=body))

    @property
    def translation(self) -> list[float]:
        return self.state()["translation"]

    @translation.setter
    def translation(self, value: Sequence[float]) -> None:
        self.pose(translation=value)

    @property
    def rotation(self) -> list[float]:
        return self.state()["rotation"]

    @rotation.setter
    def rotation(self, value: Sequence[float]) -> None:
        self.pose(rotation=value)

    @property
    def scale(self) -> list[float]:
        return self.state()["scale"]

    @scale.setter
    def scale(self, value: Sequence[float]) -> None:
        self.pose(scale=value)

    @property
    def visible(self) -> bool:
        return bool(self.state()["visible"])

    @visible.setter
    def visible(self, value: bool) -> None:
        self.pose(visible=bool(value))

    def __repr__(self) -> str:
        return f"SceneObject({self.name!r})"


class Objects(Mapping[str, SceneObject]):
    """The scene's named objects by name (parents first); a missing name is a KeyError."""

    def __init__(self, session: Session) -> None:
        self.session = session

    def __getitem__(self, name: str) -> SceneObject:
        if name not in described(self.session):
            raise KeyError(name)
        return SceneObject(self.session, name)

    def __iter__(self) -> Iterator[str]:
        return iter(described(self.session))

    def __len__(self) -> int:
        return len(described(self.session))


class Animation:
    """The scene's animation clock: :meth:`play`, :meth:`pause`, ``time`` (s, settable: a jump),
    ``speed`` (scene seconds per second, settable), ``playing``; a scene without animations
    refuses with 409."""

    def __init__(self, session: Session) -> None:
        self.session = session

    def state(self) -> dict[str, Any]:
        """``playing``, ``time``, ``speed``, ``start``, ``end`` and the scene's ``animations``."""
        return self.session.wait_ready().call("GET", "animation")

    def set(self, **fields: Any) -> int:
        """Any of ``playing``, ``time``, ``speed``; returns the first frame id showing it."""
        body = {key: (value if isinstance(value, bool) else float(value)) for key, value in fields.items()}
        return self.session.changed(self.session.call("PUT", "animation", json=body))

    def play(self, speed: float | None = None) -> int:
        return self.set(playing=True) if speed is None else self.set(playing=True, speed=speed)

    def pause(self) -> int:
        return self.set(playing=False)

    @property
    def playing(self) -> bool:
        return bool(self.state()["playing"])

    @property
    def time(self) -> float:
        return float(self.state()["time"])

    @time.setter
    def time(self, value: float) -> None:
        self.set(time=value)

    @property
    def speed(self) -> float:
        return float(self.state()["speed"])

    @speed.setter
    def speed(self, value: float) -> None:
        self.set(speed=value)
