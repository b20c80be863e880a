"""JSON control messages of a display wall's viewers (issue 22), in the catalogue's style
(:mod:`tessera.wire.messages`): the frame lock (seed 004: deliver first, swap second) and the
clock exchange it is measured with.

coordinator → viewer: ``wall`` :class:`WallHello` (after ``hello``: the wall's layout and the cell
the viewer shows, null for a whole-wall viewer), ``present`` :class:`PresentFrame` (every cell
holds frame K: show it in the animation frame whose time is nearest ``at_ms``, the coordinator's
clock), ``pong`` :class:`ClockPong` (the answer to a ping, with the coordinator's clock).

viewer → coordinator: ``ping`` :class:`ClockPing` (the viewer's clock when sent), ``have``
:class:`HaveFrame` (a cell decoded frame K and holds it), ``presented`` :class:`FramePresented`
(when a cell showed frame K, on the coordinator's clock as the viewer estimates it).

Every clock here is in milliseconds: a viewer's ``performance.now()``, the coordinator's
monotonic clock.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field, StrictInt

from tessera.wire.messages import Int, Message, NonNegative, Number

#: Largest frame id a viewer may name (a u32 in the frame header).
MAX_FRAME_ID = 2**32 - 1
FrameId = Annotated[StrictInt, Field(ge=0, le=MAX_FRAME_ID)]


class WallHello(Message):
    """The wall (``cols``, ``rows``, ``cell``, ``bezel``, as in ``POST /api/sessions``) and
    ``cell`` [col, row] this viewer shows (None: the whole wall)."""

    kind = "wall"
    wall: dict[str, Any]
    cell: tuple[Int, Int] | None


class PresentFrame(Message):
    """Show frame ``frame`` in the animation frame whose time is nearest ``at_ms`` (the
    coordinator's clock): every cell swaps on the same display refresh, however late the message
    reached it (before ``at_ms``)."""

    kind = "present"
    frame: FrameId
    at_ms: NonNegative


class ClockPong(Message):
    """``t0``: the ping's viewer clock, echoed; ``clock_ms``: the coordinator's clock when it answered."""

    kind = "pong"
    t0: Number
    clock_ms: Number


class ClockPing(Message):
    """A wall cell's clock probe: its clock ``t0`` (ms), echoed in ``pong``."""

    kind = "ping"
    t0: Number


class HaveFrame(Message):
    """A wall cell decoded frame ``frame`` and holds it, ready to present."""

    kind = "have"
    frame: FrameId


class FramePresented(Message):
    """Frame ``frame`` went on screen at ``at_ms`` (the coordinator's clock, as the viewer estimates it)."""

    kind = "presented"
    frame: FrameId
    at_ms: NonNegative


#: What the coordinator accepts from a wall's viewers, beyond :data:`tessera.wire.messages.FROM_VIEWER`.
FROM_WALL_VIEWER = (ClockPing, HaveFrame, FramePresented)
