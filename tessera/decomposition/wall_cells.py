"""A display wall's cells (issue 22, seed 004): C × R screens of ``cell`` = (w, h) px each,
``bezel`` = (bx, by) px of mullion between neighbours, shown as one frame of
C·w + (C−1)·bx by R·h + (R−1)·by px rendered with one camera (bezel compensation: the pixels
behind the mullions are part of the frustum and are never shown).

The partition a session's balancer makes over the whole wall is cut at the cell edges
(:meth:`WallLayout.cut`), so every tile lies inside one cell or inside the bezel: a cell's viewer
gets the tiles of its cell as the nodes encoded them, with no decode or re-encode on the
coordinator. The pieces of one tile name it (:meth:`WallLayout.pieces`), so a node draws the
tile once and encodes each piece on its own. Pure: rects and partitions in, rects and partitions out.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

from tessera.balancers.base import Partition, Tile
from tessera.geometry import Rect

#: Most cells of one wall.
MAX_CELLS = 64
#: Longest side of a whole wall, px: every node draws a tile into a frame-sized framebuffer,
#: and 16384 is the common GL limit (llvmpipe's among them).
MAX_WALL_SIDE = 16384


class WallError(ValueError):
    """Wall parameters that do not make a wall; the text says why."""


@dataclass(frozen=True, slots=True)
class WallLayout:
    """``cols`` × ``rows`` cells of ``cell`` = (w, h) px, ``bezel`` = (bx, by) px apart."""

    cols: int
    rows: int
    cell: tuple[int, int]
    bezel: tuple[int, int] = (0, 0)

    @classmethod
    def checked(cls, cols: int, rows: int, cell: Sequence[int], bezel: Sequence[int] | None = None,
                largest_cell: tuple[int, int] | None = None, most_pixels: int | None = None) -> WallLayout:
        """The wall, or WallError saying what is wrong: no cells, more than :data:`MAX_CELLS`, a cell
        side below 1 or over ``largest_cell`` (w, h), a negative bezel, a whole wall over
        :data:`MAX_WALL_SIDE` a side or over ``most_pixels``."""
        bezel = (0, 0) if bezel is None else bezel
        values = [cols, rows, *cell, *bezel]
        if len(cell) != 2 or len(bezel) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) for v in values):
            raise WallError("a wall is cols, rows (whole numbers), cell [w, h] and bezel [bx, by] (whole numbers)")
        if cols < 1 or rows < 1:
            raise WallError(f"a wall has at least one cell a side, got {cols}x{rows} cells")
        if cols * rows > MAX_CELLS:
            raise WallError(f"a wall has at most {MAX_CELLS} cells, got {cols}x{rows}")
        if cell[0] < 1 or cell[1] < 1:
            raise WallError(f"a cell is at least 1x1 px, got {cell[0]}x{cell[1]}")
        if largest_cell is not None and (cell[0] > largest_cell[0] or cell[1] > largest_cell[1]):
            raise WallError(f"a cell of {cell[0]}x{cell[1]} px is larger than the largest frame, "
                            f"{largest_cell[0]}x{largest_cell[1]} (--max-size)")
        if bezel[0] < 0 or bezel[1] < 0:
            raise WallError(f"a bezel is at least 0 px, got {bezel[0]}x{bezel[1]}")
        wall = cls(cols, rows, (cell[0], cell[1]), (bezel[0], bezel[1]))
        width, height = wall.size
        if width > MAX_WALL_SIDE or height > MAX_WALL_SIDE:
            raise WallError(f"the whole wall, {width}x{height} px, is over {MAX_WALL_SIDE} px a side")
        if most_pixels is not None and width * height > most_pixels:
            raise WallError(f"the whole wall, {width}x{height} px, is over the session pixel budget "
                            f"({most_pixels} px: 4 × --max-size)")
        return wall

    @classmethod
    def from_json(cls, value: Mapping[str, Any], largest_cell: tuple[int, int] | None = None,
                  most_pixels: int | None = None) -> WallLayout:
        """``{"cols", "rows", "cell": [w, h], "bezel": [bx, by]?}`` checked as :meth:`checked`."""
        try:
            return cls.checked(value["cols"], value["rows"], list(value["cell"]),
                               None if value.get("bezel") is None else list(value["bezel"]), largest_cell, most_pixels)
        except (KeyError, TypeError):
            raise WallError("a wall is {\"cols\", \"rows\", \"cell\": [w, h], \"bezel\": [bx, by]?}") from None

    def to_json(self) -> dict[str, Any]:
        return {"cols": self.cols, "rows": self.rows, "cell": list(self.cell), "bezel": list(self.bezel)}

    @property
    def size(self) -> tuple[int, int]:
        """The whole wall (w, h) px, bezels included."""
        (w, h), (bx, by) = self.cell, self.bezel
        return self.cols * w + (self.cols - 1) * bx, self.rows * h + (self.rows - 1) * by

    @property
    def cells(self) -> list[tuple[int, int]]:
        """Every (col, row), row by row from the top left."""
        return [(col, row) for row in range(self.rows) for col in range(self.cols)]

    def cell_rect(self, col: int, row: int) -> Rect:
        """Where cell (``col``, ``row``) lies in the whole wall's frame; WallError outside the wall."""
        self.check_cell(col, row)
        (w, h), (bx, by) = self.cell, self.bezel
        return Rect(col * (w + bx), row * (h + by), w, h)

    def check_cell(self, col: int, row: int) -> None:
        if not (0 <= col < self.cols and 0 <= row < self.rows):
            raise WallError(f"cell {col},{row} is outside the wall of {self.cols}x{self.rows} cells "
                            f"(col 0…{self.cols - 1}, row 0…{self.rows - 1})")

    def _edges(self, count: int, length: int, gap: int) -> list[int]:
        """Where cells start and end along one axis (px), in order, each once (without a bezel a
        cell ends where the next starts)."""
        return sorted({edge for index in range(count) for edge in (index * (length + gap),
                                                                  index * (length + gap) + length)})

    def cut(self, partition: Partition) -> Partition:
        """``partition`` with every tile cut at the cell edges: each piece lies inside one cell or
        inside the bezel, keeps its tile's node, and pieces of one tile follow each other (a pull
        list keeps its order); still an exact cover of the wall."""
        return self.pieces(partition)[0]

    def pieces(self, partition: Partition) -> tuple[Partition, tuple[Rect | None, ...]]:
        """:meth:`cut` of ``partition``, and for each of its tiles the rect of the tile of
        ``partition`` it is a piece of (None: a tile no cell edge crosses, kept whole). A node draws
        the pieces of one tile as that one rect and sends each piece on its own."""
        xs = self._edges(self.cols, self.cell[0], self.bezel[0])
        ys = self._edges(self.rows, self.cell[1], self.bezel[1])
        tiles: list[Tile] = []
        parts: list[Rect | None] = []
        for tile in partition.tiles:
            r = tile.rect
            cuts_x = [r.x, *(x for x in xs if r.x < x < r.x1), r.x1]
            cuts_y = [r.y, *(y for y in ys if r.y < y < r.y1), r.y1]
            if len(cuts_x) == 2 and len(cuts_y) == 2:
                tiles.append(tile)
                parts.append(None)
                continue
            for y0, y1 in pairwise(cuts_y):
                for x0, x1 in pairwise(cuts_x):
                    tiles.append(Tile(Rect(x0, y0, x1 - x0, y1 - y0), tile.node_id))
                    parts.append(r)
        return Partition(tuple(tiles), partition.pull), tuple(parts)

    def in_cell(self, rects: Sequence[Rect], col: int, row: int) -> list[tuple[int, Rect]]:
        """The rects (of a :meth:`cut` partition) inside cell (``col``, ``row``): each one's index
        in ``rects`` and its rect relative to the cell's top-left corner."""
        cell = self.cell_rect(col, row)
        return [(index, Rect(r.x - cell.x, r.y - cell.y, r.w, r.h)) for index, r in enumerate(rects)
                if cell.x <= r.x and r.x1 <= cell.x1 and cell.y <= r.y and r.y1 <= cell.y1]


def parse_cell(text: str) -> tuple[int, int]:
    """``"COL,ROW"`` → (col, row); WallError for anything else."""
    parts = text.split(",")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise WallError(f"a cell is COL,ROW (two whole numbers from 0), got {text!r}")
    return int(parts[0]), int(parts[1])
