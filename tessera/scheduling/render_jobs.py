"""Render jobs (issue 35): posters and films, a session's work on the cluster beside its frames.

A job is a list of pictures, each a camera (a poster: one, at the session's camera; a film: one
per frame of a camera path or an orbit), all of one ``size``, in the session's scene state, clip
and selection when the job was made, each accumulated from ``plan``'s jittered samples exactly as
the still (:mod:`tessera.scheduling.refinement`: a fixed count, so that ``--render-once --samples
N`` of the same size is the same picture, bit for bit). Every picture is cut into *pieces*, and
each sample of a piece is one unit of work (:class:`JobItem`), drawn by one node as a one-tile frame
(:class:`tessera.scheduling.job_scheduler.JobScheduler`): many small pieces spread over all nodes
and interleave with the sessions' frames, which go first.

* **Windows.** A picture of at most :data:`WHOLE_SIDE` px a side is drawn as every frame is, into
  a frame-sized framebuffer with the full frame's projection (its pieces are then bit for bit the
  whole frame's, whatever their size). A larger one (a poster of up to :data:`MAX_POSTER_SIDE`) is
  cut into windows of at most :data:`WHOLE_SIDE` a side, each drawn into a framebuffer of its own
  size with the projection narrowed to it (:func:`tessera.tools.picking.window_matrix`), grown by
  :data:`WINDOW_MARGIN` px on inner edges so that a filtered sample's guard band reads real pixels;
  ``--render-once`` of that size draws the same windows, so pieces of any size join without seams
  and equal it.
* **Pieces** are squares of about :func:`piece_side` px, which a node draws one sample of in about
  :data:`PIECE_MS` (from the nodes' measured rate), inside one window.
* **Order.** Pictures are worked on in order and at most :data:`LOOKAHEAD` ahead of the oldest
  unfinished one (a film's frames are encoded in order, and those waiting are held in memory).

Pure: no I/O, the pixels are the coordinator's (:mod:`server.render_jobs`).
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from tessera.geometry import Camera, Rect
from tessera.scene.state import SceneState
from tessera.scheduling.refinement import StillPlan
from tessera.tools.clipping import ClipState

#: Largest side of a picture drawn whole, as the live frames are (larger: by windows).
WHOLE_SIDE = 4096
#: Largest side of a poster.
MAX_POSTER_SIDE = 16384
#: Pixels a window's framebuffer reaches beyond its cell on inner edges (a filtered sample's guard band).
WINDOW_MARGIN = 1
#: Node time (ms) one sample of a piece should take: the longest a session's next frame waits
#: behind job work on a node.
PIECE_MS = 50.0
#: Side (px) of a piece before any node's rate is known, and the smallest and largest side.
DEFAULT_PIECE_SIDE = 256
MIN_PIECE_SIDE, MAX_PIECE_SIDE = 64, 1024
#: Pictures of a job worked on at once beyond the oldest unfinished one.
LOOKAHEAD = 3

QUEUED, RENDERING, DONE, ERROR, CANCELLED = "queued", "rendering", "done", "error", "cancelled"
#: States a job no longer changes from.
FINISHED = (DONE, ERROR, CANCELLED)


def piece_side(ms_per_px: float | None, target_ms: float = PIECE_MS) -> int:
    """The side (px, even) of a square piece a node whose busy time per pixel is ``ms_per_px`` draws
    one sample of in about ``target_ms`` (None: not known yet, :data:`DEFAULT_PIECE_SIDE`)."""
    if ms_per_px is None or not ms_per_px > 0.0:
        return DEFAULT_PIECE_SIDE
    side = int(math.sqrt(target_ms / ms_per_px)) // 2 * 2
    return max(MIN_PIECE_SIDE, min(MAX_PIECE_SIDE, side))


def windows(size: tuple[int, int]) -> list[tuple[Rect, Rect]]:
    """(cell, window) pairs of a ``size`` = (w, h) picture: the cells tile it (rows top to bottom),
    each window is its cell grown by :data:`WINDOW_MARGIN` inside the picture (the framebuffer it is
    drawn in). One pair, the whole picture twice, when neither side exceeds :data:`WHOLE_SIDE`."""
    width, height = size
    if width <= WHOLE_SIDE and height <= WHOLE_SIDE:
        whole = Rect(0, 0, width, height)
        return [(whole, whole)]
    out = []
    for y in range(0, height, WHOLE_SIDE):
        for x in range(0, width, WHOLE_SIDE):
            cell = Rect(x, y, min(WHOLE_SIDE, width - x), min(WHOLE_SIDE, height - y))
            x0, y0 = max(cell.x - WINDOW_MARGIN, 0), max(cell.y - WINDOW_MARGIN, 0)
            x1, y1 = min(cell.x1 + WINDOW_MARGIN, width), min(cell.y1 + WINDOW_MARGIN, height)
            out.append((cell, Rect(x0, y0, x1 - x0, y1 - y0)))
    return out


def window_of(rect: Rect, size: tuple[int, int]) -> Rect | None:
    """The window ``rect`` is drawn in (None: the whole picture, drawn as a frame); ValueError when
    ``rect`` crosses cells."""
    cells = windows(size)
    for cell, window in cells:
        if cell.x <= rect.x and rect.x1 <= cell.x1 and cell.y <= rect.y and rect.y1 <= cell.y1:
            return None if len(cells) == 1 else window
    raise ValueError(f"rect {rect.as_list()} crosses the windows of a {size[0]}x{size[1]} picture")


def pieces(size: tuple[int, int], side: int) -> list[tuple[Rect, Rect | None]]:
    """(piece, window) pairs cutting a ``size`` picture into pieces of at most ``side`` px a side
    (even cuts of each cell), each inside one window (None: drawn as a whole frame)."""
    out: list[tuple[Rect, Rect | None]] = []
    cells = windows(size)
    for cell, window in cells:
        columns, rows = -(-cell.w // side), -(-cell.h // side)
        xs = [cell.x + cell.w * i // columns for i in range(columns + 1)]
        ys = [cell.y + cell.h * j // rows for j in range(rows + 1)]
        for j in range(rows):
            for i in range(columns):
                out.append((Rect(xs[i], ys[j], xs[i + 1] - xs[i], ys[j + 1] - ys[j]),
                            None if len(cells) == 1 else window))
    return out


@dataclass(frozen=True, slots=True)
class JobItem:
    """One unit of a job's work: sample ``sample`` of piece ``piece`` of picture ``picture``."""

    picture: int
    piece: int
    sample: int


@dataclass
class JobSpec:
    """What a job draws: ``cameras`` (one per picture), ``size`` (w, h), ``plan`` (its samples), the
    scene ``state`` (None: the base pose), ``clip`` and ``highlight`` of its session when it was
    made, of session ``session`` whose nodes hold ``scene``; ``kind`` "poster" or "film"."""

    kind: str
    session: str
    scene: str | None
    cameras: Sequence[Camera]
    size: tuple[int, int]
    plan: StillPlan
    state: SceneState | None = None
    clip: ClipState | None = None
    highlight: str | None = None

    def __post_init__(self) -> None:
        if self.plan.adaptive:
            raise ValueError("a render job takes a fixed number of samples")
        if not self.cameras:
            raise ValueError("a render job draws at least one picture")


@dataclass
class RenderWork:
    """A job's work as the scheduler hands it out: ``spec``, its pieces (cut with ``side``), what
    waits, what is out, what is done; ``state`` and ``reason`` (a job that failed or was cancelled)."""

    job_id: str
    spec: JobSpec
    side: int = DEFAULT_PIECE_SIDE
    state: str = QUEUED
    reason: str | None = None
    pieces: list[tuple[Rect, Rect | None]] = field(default_factory=list)
    #: Items handed back (a node left, a tile failed): handed out again first.
    again: deque[JobItem] = field(default_factory=deque)
    out: set[JobItem] = field(default_factory=set)
    #: Pieces of each picture whose every sample is in, and the pictures whose every piece is.
    pieces_done: dict[int, set[int]] = field(default_factory=dict)
    pictures_done: int = 0
    #: Items drawn so far, and the node time (busy ms: render, read-back, encode) they took.
    items_drawn: int = 0
    node_ms: float = 0.0
    #: The node time (ms) of each piece's latest sample drawn, by piece (a film's next picture
    #: costs about what the one before did, piece by piece).
    piece_ms: dict[int, float] = field(default_factory=dict)
    #: The next picture to start and, in it, the next piece and sample.
    _cursor: tuple[int, int, int] = (0, 0, 0)
    _samples_done: dict[tuple[int, int], int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.pieces = pieces(self.spec.size, self.side)

    @property
    def samples(self) -> int:
        return self.spec.plan.samples

    @property
    def total(self) -> int:
        """Units of progress: a film's frames, a poster's piece samples."""
        if self.spec.kind == "film":
            return len(self.spec.cameras)
        return len(self.pieces) * self.samples

    @property
    def done(self) -> int:
        """Progress so far, in :attr:`total`'s units."""
        if self.spec.kind == "film":
            return self.pictures_done
        return self.items_drawn

    @property
    def finished(self) -> bool:
        return self.state in FINISHED

    @property
    def waiting(self) -> bool:
        """An item could be handed out now."""
        return not self.finished and (bool(self.again) or self._next_new() is not None)

    def _next_new(self) -> JobItem | None:
        picture, piece, sample = self._cursor
        if picture >= len(self.spec.cameras) or picture > self.pictures_done + LOOKAHEAD:
            return None
        return JobItem(picture, piece, sample)

    def take(self) -> JobItem | None:
        """The next item to draw (one handed back first, else the next in order); None: none now."""
        if self.finished:
            return None
        item = self.again.popleft() if self.again else self._next_new()
        if item is None:
            return None
        if item == self._next_new():
            picture, piece, sample = self._cursor
            sample += 1
            if sample == self.samples:
                piece, sample = piece + 1, 0
                if piece == len(self.pieces):
                    picture, piece = picture + 1, 0
            self._cursor = (picture, piece, sample)
        self.state = RENDERING
        self.out.add(item)
        return item

    def hand_back(self, item: JobItem) -> None:
        """``item`` was not drawn (its node left, its frame was dropped): it goes out again first."""
        if item in self.out:
            self.out.discard(item)
            if not self.finished:
                self.again.append(item)

    def drawn(self, item: JobItem, busy_ms: float = 0.0) -> tuple[bool, bool]:
        """``item`` came back, having taken ``busy_ms`` of node time: (its piece has every sample
        now, its picture every piece)."""
        self.out.discard(item)
        self.items_drawn += 1
        self.node_ms += busy_ms
        self.piece_ms[item.piece] = busy_ms
        key = (item.picture, item.piece)
        self._samples_done[key] = self._samples_done.get(key, 0) + 1
        if self._samples_done[key] < self.samples:
            return False, False
        done = self.pieces_done.setdefault(item.picture, set())
        done.add(item.piece)
        return True, len(done) == len(self.pieces)

    def picture_finished(self, picture: int) -> None:
        """The coordinator has taken picture ``picture`` whole (encoded, written): later ones may start."""
        self.pictures_done = max(self.pictures_done, picture + 1)
        self.pieces_done.pop(picture, None)
        for key in [key for key in self._samples_done if key[0] == picture]:
            del self._samples_done[key]

    def end(self, state: str, reason: str | None = None) -> list[JobItem]:
        """The job is ``state`` (done, error, cancelled) with ``reason``; returns the items still out."""
        self.state, self.reason = state, reason
        out, self.out = list(self.out), set()
        self.again.clear()
        return out

    def describe(self) -> dict[str, object]:
        """``{"state", "done", "total", "node_ms", "reason"?}`` (``node_ms``: the node time its tiles took)."""
        return {"state": self.state, "done": self.done, "total": self.total, "node_ms": round(self.node_ms, 1),
                **({"reason": self.reason} if self.reason is not None else {})}


def orbit_cameras(camera: Camera, turns: float, frames: int) -> list[Camera]:
    """``frames`` cameras whose eye turns ``turns`` times around ``camera``'s target about its up
    axis, starting at ``camera`` (the last one short of where the first would come again)."""
    eye, target = np.asarray(camera.eye, dtype=np.float64), np.asarray(camera.target, dtype=np.float64)
    axis = np.asarray(camera.up, dtype=np.float64)
    axis /= np.linalg.norm(axis)
    offset = eye - target
    along = axis * float(np.dot(offset, axis))
    radial, side = offset - along, np.cross(axis, offset - along)
    out = []
    for k in range(frames):
        angle = 2.0 * math.pi * turns * k / frames
        turned = target + along + radial * math.cos(angle) + side * math.sin(angle)
        out.append(dataclasses.replace(camera, eye=(float(turned[0]), float(turned[1]), float(turned[2]))))
    return out


def items_of(work: RenderWork) -> Iterator[JobItem]:
    """Every item of ``work`` in the order :meth:`RenderWork.take` hands them out (for tests)."""
    for picture in range(len(work.spec.cameras)):
        for piece in range(len(work.pieces)):
            for sample in range(work.samples):
                yield JobItem(picture, piece, sample)
