"""JSON control messages of picking (issue 35), in the catalogue's style (:mod:`tessera.wire.messages`).

coordinator → node: ``pick`` :class:`Pick` — which surface one pixel's centre sees, drawn as an id
pass of that pixel alone, ahead of the tiles queued (its state is whole: it leaves the node's
scene state as it was).

node → coordinator: ``pick_result`` :class:`PickResult` — what the pixel's centre sees, or why it
could not be told.
"""

from __future__ import annotations

from typing import Annotated, Any, Self

from pydantic import Field, StrictBool, StrictInt, model_validator

from tessera.scene.state import StateDelta
from tessera.wire.messages import (
    MAX_SIDE,
    CameraJson,
    ClipJson,
    Message,
    NonNegative,
    Size,
    StateJson,
    Text,
    Vec3,
)


class Pick(Message):
    """Request ``id``: which surface the centre of pixel (``x``, ``y``) of a ``size`` frame of
    ``camera`` sees, of scene spec ``scene`` (None: the scene loaded last) in the whole scene
    ``state`` (None: the base pose), cut by ``clip``; in sort-last, of the node's share of
    partition ``share``."""

    kind = "pick"
    id: Annotated[StrictInt, Field(ge=0)]
    camera: CameraJson
    size: Size
    x: Annotated[StrictInt, Field(ge=0, lt=MAX_SIDE)]
    y: Annotated[StrictInt, Field(ge=0, lt=MAX_SIDE)]
    scene: Text | None = None
    state: StateJson | None = None
    clip: ClipJson | None = None
    share: Annotated[StrictInt, Field(ge=1)] | None = None

    @model_validator(mode="after")
    def _pixel_in_frame_state_whole(self) -> Self:
        if self.x >= self.size[0] or self.y >= self.size[1] or isinstance(self.state, StateDelta):
            raise ValueError(f"pixel ({self.x}, {self.y}) outside the {self.size[0]}x{self.size[1]} frame, or a delta")
        return self

    def to_json(self) -> dict[str, Any]:
        return self._without_none(super().to_json(), "scene", "state", "clip", "share")


class PickResult(Message):
    """The answer to pick ``id``: ``hit`` and, when it is, the ``object`` (its name), the
    ``primitive`` (the triangle's number among the object's), the world ``point``, the unit
    ``normal`` facing the eye and the ``depth`` (the point's distance from the eye); ``error``: why
    the node could not tell (then ``hit`` is false)."""

    kind = "pick_result"
    id: Annotated[StrictInt, Field(ge=0)]
    hit: StrictBool
    object: Text | None = None
    primitive: Annotated[StrictInt, Field(ge=0)] | None = None
    point: Vec3 | None = None
    normal: Vec3 | None = None
    depth: NonNegative | None = None
    error: Text | None = None

    @model_validator(mode="after")
    def _whole_hit(self) -> Self:
        if self.hit and None in (self.object, self.primitive, self.point, self.normal, self.depth):
            raise ValueError("a hit names its object, primitive, point, normal and depth")
        return self

    def to_json(self) -> dict[str, Any]:
        return self._without_none(super().to_json(), "object", "primitive", "point", "normal", "depth", "error")


#: What a node accepts from the coordinator besides :data:`tessera.wire.messages.TO_NODE`.
TO_NODE_PICKS = (Pick,)
#: What the coordinator accepts from a node besides :data:`tessera.wire.messages.FROM_NODE`.
FROM_NODE_PICKS = (PickResult,)
