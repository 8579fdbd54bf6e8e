"""How much memory one import may take, estimated from a file's header before anything is decoded.

An import holds, at its peak, about

    pixels x (bytes a pixel) + cells x (bytes a cell) + one band of pixels being converted

where a pixel costs, while it is decoded, what the decoder keeps (Pillow: 1 byte for 1-bit,
grey and palette images, 2 for 16-bit grey, 4 for the rest) and the grey level read from it,
then (the decoder's image freed) the reader's masks (wall and floor, or occupied and free, and
their padded copies while pixels are merged: 4 bytes), and 1 byte more for opacity when the
image has transparency; a Moving AI map's character costs its text, rows and terrain masks
(12 bytes); and a cell (pixels / merge^2 of them, or a Moving AI map's characters) costs what
region labelling, placing the start and goals, the written map's checks and its distances to
every goal hold at once (544 bytes with up to 8 goals, 10 more for each goal beyond).

An IMDF archive (:mod:`app.mapio.imdf`) is checked twice: its GeoJSON's bytes (the files'
sizes, before parsing) at :data:`JSON_BYTE_COST` a byte, the worst a JSON document costs while
parsed; then, from the features' extent and the resolution before anything is drawn, the cells
of every level (:data:`VENUE_LEVEL_CELL_BYTES` each, all levels being drawn before the
connections between them are found), of the level being drawn
(:data:`VENUE_BUILD_CELL_BYTES`) and of the level placed as a map (a cell's cost, as above),
with the records read (:data:`RECORD_BYTE_COST` a byte of GeoJSON).

The constants are peak RSS over a tiny import's, measured with ``python -m
tests.reliability.map_import_figures`` (every Pillow mode the readers take, ROS and Moving AI
maps, 1,000 x 1,000 to 20,000 x 20 cells, merged and not) and rounded up: the peaks were 67 to
91 % of the estimate. The estimate is checked against :class:`MemoryBudget` before decoding,
and the import refused past it with a message naming the size, the estimate, the budget and
how to raise it (``--max-memory``) or to need less (``--merge``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from app.mapio import MapImportError

MIB = 1 << 20
#: the default budget of an import (``maze import --max-memory``), in MiB
DEFAULT_MAX_MEMORY_MIB = 768

#: bytes a cell of the imported grid costs until the map is written, with up to
#: :data:`GOALS_INCLUDED` goals (measured on maps all floor, 1 to 8 goals, the pixels' cost
#: included: 380 to 494, depending on the shape)
CELL_BYTES = 544
GOALS_INCLUDED = 8
#: bytes a cell costs for each goal beyond those: the written map's distances to it (int64)
#: and the searches' frontiers (measured with 100 and 400 goals: 7.7)
GOAL_CELL_BYTES = 10
#: bytes a pixel costs once decoded into grey levels, the decoder's image freed: the reader's
#: masks (wall and floor, or occupied and free) and their padded copies while cells are merged
READ_PIXEL_BYTES = 4
#: pixels converted at a time (a band of whole rows), and what each holds meanwhile (the cropped
#: band, its RGB(A) or float copy, the conversion's temporaries)
BAND_PIXELS = 1 << 18
BAND_PIXEL_BYTES = 64
#: a Moving AI map: bytes a character costs while the text is read and parsed (the file's bytes,
#: its text, the rows, joined and encoded, the terrain masks), and each row's string and places
TEXT_CELL_BYTES = 12
TEXT_ROW_BYTES = 128
#: an IMDF archive: bytes a byte of its GeoJSON costs while it is parsed and checked (the file's
#: bytes and text, Python's objects of the document, the records' arrays), at worst: a document
#: of empty lists or objects (``[[],[],...]``) costs 25 bytes a byte once parsed (measured with
#: tracemalloc; real IMDF files 3 to 7)
JSON_BYTE_COST = 32
#: bytes a byte of GeoJSON costs once read into records (their arrays and strings: measured 1.2
#: to 3), kept while the levels are drawn, and while one polygon is drawn its edges (about 115
#: bytes an edge, an edge at least 6 bytes of GeoJSON)
RECORD_BYTE_COST = 24
#: bytes a cell costs on every level of a venue while connections are found (its owners, the
#: walkable and free masks, the level's copy, and the connections' cells there, 8 bytes each
#: at worst), and once more for the level being drawn or the stop being gathered (walls,
#: windows, temporaries). Measured with tracemalloc against the estimate: 34 to 40 % on rooms
#: along corridors (2 to 10 levels of 0.4 to 1.6 million cells, 50 to 1,600 rooms a level) and
#: on 300 thin walkways across each level, 60 % with every room a stairwell, 85 % with one
#: stairwell over each whole level, stacked on 4 levels
VENUE_LEVEL_CELL_BYTES = 16
VENUE_BUILD_CELL_BYTES = 24

#: the smallest cost of a pixel (a grey image merged into few cells): Pillow's own limit on an
#: image's pixels (``Image.MAX_IMAGE_PIXELS``) is the budget divided by it while decoding
CHEAPEST_PIXEL_BYTES = READ_PIXEL_BYTES


def decoded_bytes(mode: str) -> int:
    """Bytes a pixel of a Pillow image of ``mode`` takes once decoded."""
    if mode in ("1", "L", "P"):
        return 1
    if mode.startswith("I;16"):
        return 2
    return 4


def mib(n: int) -> str:
    """``n`` bytes in whole MiB, rounded up, with thousands separators."""
    return f"{-(-n // MIB):,} MiB"


@dataclass(frozen=True)
class MemoryBudget:
    """At most ``limit`` bytes for one import, whose written map gets ``goals`` goals;
    ``placed``: the levels of a venue placed as the map (all of them for a map of several
    floors)."""

    limit: int = DEFAULT_MAX_MEMORY_MIB * MIB
    goals: int = 8
    placed: int = 1

    @classmethod
    def of_mib(cls, mebibytes: int, goals: int = 8) -> MemoryBudget:
        return cls(mebibytes * MIB, goals)

    @property
    def cell_bytes(self) -> int:
        return CELL_BYTES + GOAL_CELL_BYTES * max(0, self.goals - GOALS_INCLUDED)

    @property
    def max_pixels(self) -> int:
        """The most pixels any image can have under this budget (Pillow's limit)."""
        return max(1, self.limit // CHEAPEST_PIXEL_BYTES)

    def image_estimate(
        self, width: int, height: int, mode: str, merge: int, alpha: bool = False
    ) -> int:
        """Bytes an import of a ``width`` x ``height`` image of Pillow ``mode`` holds at most,
        read with ``merge`` x ``merge`` pixels a cell (``alpha``: the image has transparency)."""
        # decoding: Pillow's image, the grey levels and opacity; then (Pillow's image freed)
        # the opacity and the reader's masks
        per_pixel = int(alpha) + max(decoded_bytes(mode) + 1, READ_PIXEL_BYTES)
        band = max(BAND_PIXELS, width) * BAND_PIXEL_BYTES
        return width * height * per_pixel + band + _cells(width, height, merge) * self.cell_bytes

    def text_estimate(self, width: int, height: int) -> int:
        """Bytes an import of a Moving AI map of ``height`` rows of ``width`` holds at most."""
        return width * height * (TEXT_CELL_BYTES + self.cell_bytes) + height * TEXT_ROW_BYTES

    def check_image(
        self, where: str, width: int, height: int, mode: str, merge: int, alpha: bool = False
    ) -> None:
        """Refuse an image whose import would take more than the budget, before decoding."""
        need = self.image_estimate(width, height, mode, merge, alpha)
        if need <= self.limit:
            return
        hint = ""
        lo, hi = merge + 1, max(width, height, merge + 1)  # cells only fall as merge grows
        if self.image_estimate(width, height, mode, hi, alpha) <= self.limit:
            while lo < hi:
                mid = (lo + hi) // 2
                if self.image_estimate(width, height, mode, mid, alpha) <= self.limit:
                    hi = mid
                else:
                    lo = mid + 1
            hint = f", or read {lo} x {lo} pixels a cell with --merge {lo}"
        raise MapImportError(
            f"{where}: a {width} x {height} pixel image (mode {mode}) would need about "
            f"{mib(need)} to import at --merge {merge}, more than the memory budget of "
            f"{mib(self.limit)}: raise the budget with --max-memory MIB{hint}"
        )

    def venue_estimate(self, rows: int, cols: int, levels: int, json_bytes: int = 0) -> int:
        """Bytes an import of a venue of ``levels`` levels of ``rows`` x ``cols`` cells, read
        from ``json_bytes`` of GeoJSON, holds at most: the records, every level drawn, one level
        being drawn, and ``placed`` placed as a map."""
        cells = rows * cols
        placed = self.placed * self.cell_bytes
        per_cell = levels * VENUE_LEVEL_CELL_BYTES + VENUE_BUILD_CELL_BYTES + placed
        return cells * per_cell + json_bytes * RECORD_BYTE_COST

    def check_json(self, where: str, n_bytes: int) -> None:
        """Refuse GeoJSON files whose parsing would take more than the budget, before it."""
        need = n_bytes * JSON_BYTE_COST
        if need > self.limit:
            raise MapImportError(
                f"{where}: {n_bytes:,} bytes of GeoJSON would need up to {mib(need)} to read "
                f"({JSON_BYTE_COST} bytes a byte at most), more than the memory budget of "
                f"{mib(self.limit)}: raise the budget with --max-memory MIB"
            )

    def check_venue(
        self,
        where: str,
        width_m: float,
        height_m: float,
        levels: int,
        resolution: float,
        json_bytes: int = 0,
    ) -> None:
        """Refuse a venue ``width_m`` x ``height_m`` metres of ``levels`` levels at
        ``resolution`` past the budget, before anything is drawn."""
        rows, cols = venue_cells(width_m, height_m, resolution)
        need = self.venue_estimate(rows, cols, levels, json_bytes)
        if need <= self.limit:
            return
        hint = ""
        coarser = resolution * math.sqrt(need / self.limit)
        for _ in range(60):  # a round figure that fits, a little coarser each time
            coarser = float(f"{coarser * 1.05:.2g}")
            cells = venue_cells(width_m, height_m, coarser)
            if self.venue_estimate(*cells, levels, json_bytes) <= self.limit:
                hint = f", or give a coarser --resolution (such as {coarser:g})"
                break
        raise MapImportError(
            f"{where}: {levels} level(s) of {rows:,} x {cols:,} cells ({width_m:,.0f} x "
            f"{height_m:,.0f} m at {resolution:g} m a cell) would need about {mib(need)} to "
            f"import, more than the memory budget of {mib(self.limit)}: raise the budget with "
            f"--max-memory MIB{hint}"
        )

    def check_text(self, where: str, width: int, height: int) -> None:
        """Refuse a Moving AI map whose import would take more than the budget."""
        need = self.text_estimate(width, height)
        if need > self.limit:
            raise MapImportError(
                f"{where}: a {width} x {height} map would need about {mib(need)} to import, "
                f"more than the memory budget of {mib(self.limit)}: raise the budget with "
                "--max-memory MIB"
            )


def venue_cells(width_m: float, height_m: float, resolution: float) -> tuple[int, int]:
    """Rows and columns covering ``width_m`` x ``height_m`` metres in cells of ``resolution``,
    with a cell of margin on every side (and one more for the grid's alignment)."""
    return math.ceil(height_m / resolution) + 3, math.ceil(width_m / resolution) + 3


def _cells(width: int, height: int, merge: int) -> int:
    return -(-width // merge) * -(-height // merge)
