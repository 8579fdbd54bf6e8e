"""Seeded buildings of several floors: hospitals and offices (``maze generate --kind building
--floors N``).

One floor plan's skeleton serves every floor, as a building's structure does: the rooms and
corridors of :func:`~app.domain.generate.building_layout`, made once. On it the cores sit at the
same (row, col) on every floor, in corridors:

* a lift bank (:data:`LIFTS` lifts side by side, or one where the corridor has no room for more)
  at the corridor cell nearest the middle of the plan, each lift stopping on every floor;
* two stairwells (``Stairs A``, ``Stairs B``) far apart: A the corridor cell farthest from the
  lift bank, B the one farthest from A (distances along rows and columns), each stopping on
  every floor, so that one flight joins two floors next to each other.

Each floor then gets its own doors (:func:`~app.domain.generate.doors`: the same rooms, doors
drawn again from the generator) and its own destinations: ``n_goals`` a floor, placed as a
one-floor building's (:func:`~app.domain.place.place`: spread out from where one arrives, the
entrance on the ground floor, the first lift above; never on a stair or lift). The start is
the ground floor's corridor cell nearest the lower-left corner (the entrance). Destinations
are named from the purpose's list (:data:`NAMES`), shuffled by the generator, then ``Room
F.NN`` (the floor's ordinal and a number) when the list runs out. Floors are ordinals 0 to
N - 1, ``Ground floor`` then ``Floor 1``..., :data:`STOREY_HEIGHT` metres apart. Rides cost
:func:`~app.domain.floors.default_cost` at :data:`CELL_METRES` a cell (stairs 18 moves of time
a floor, lifts 12). Every random choice goes through the ``rng`` given.
"""

from __future__ import annotations

import numpy as np

from app.arrays import BoolArray
from app.domain.building import MAX_CELLS, Building
from app.domain.floors import MAX_FLOORS, Connection, Floor, FloorName, default_cost
from app.domain.generate import building_layout, doors
from app.domain.grid import FREE, GOAL, NamedCell
from app.domain.place import place

Cell = tuple[int, int]

#: what a generated building is, and the names of its destinations
NAMES: dict[str, tuple[str, ...]] = {
    "hospital": (
        "Radiology", "Cardiology", "Oncology", "Neurology", "Maternity", "Paediatrics",
        "Emergency", "Pharmacy", "Dialysis", "Orthopaedics", "Dermatology", "Ophthalmology",
        "Physiotherapy", "Laboratory", "Outpatients", "Intensive care", "Day surgery",
        "Endoscopy", "Audiology", "Urology", "Gastroenterology", "Respiratory", "Rheumatology",
        "Haematology", "Renal unit", "Fracture clinic", "Blood tests", "X-ray", "MRI",
        "Ultrasound", "Chapel", "Cafeteria", "Shop", "Information desk", "Patient records",
        "Sexual health", "Diabetes centre", "Speech therapy", "Occupational therapy", "Dentistry",
    ),
    "office": (
        "Reception", "Accounts", "Legal", "Human resources", "Marketing", "Sales",
        "Engineering", "Design studio", "Customer support", "Facilities", "IT help desk",
        "Mail room", "Canteen", "Library", "Board room", "Print room", "Meeting room A",
        "Meeting room B", "Meeting room C", "Meeting room D", "Quiet room", "Wellness room",
        "Training room", "Archive", "Procurement", "Payroll", "Security office", "Research",
        "Finance", "Communications", "Strategy", "Data team", "Product", "Operations",
        "Innovation lab", "Recording studio", "Lounge", "Gym", "First aid room", "Kitchen",
    ),
}  # fmt: skip
PURPOSES: tuple[str, ...] = tuple(NAMES)
#: lifts in the bank
LIFTS = 2
#: metres between floors (their elevations)
STOREY_HEIGHT = 4.0
#: the metres a cell is taken to be, for the rides' costs (rooms of 3 to 7 cells)
CELL_METRES = 1.0


def generate_floors(
    rows: int,
    cols: int,
    n_floors: int,
    rng: np.random.Generator,
    *,
    purpose: str = "office",
    n_goals: int = 8,
    corridor: int = 2,
    room: tuple[int, int] = (3, 7),
    loops: float = 0.1,
    name: str = "building",
) -> Building:
    """A building of ``n_floors`` floors of ``rows`` x ``cols`` (the module docstring),
    ``n_goals`` destinations a floor; ``ValueError`` says what cannot be made."""
    if not 2 <= n_floors <= MAX_FLOORS:
        raise ValueError(f"a building of several floors has 2 to {MAX_FLOORS}, got {n_floors}")
    if purpose not in NAMES:
        raise ValueError(f"unknown purpose {purpose!r}: use one of {', '.join(PURPOSES)}")
    if n_floors * rows * cols > MAX_CELLS:
        raise ValueError(
            f"{n_floors} floors of {rows} x {cols} cells: a building holds at most "
            f"{MAX_CELLS:,} cells"
        )
    if rows < 3 or cols < 3:
        raise ValueError(f"a building needs at least 3 rows and 3 columns, got {rows}x{cols}")
    if not 0.0 <= loops <= 1.0:
        raise ValueError(f"loops must be in [0, 1], got {loops}")
    if corridor < 1 or not 1 <= room[0] <= room[1]:
        raise ValueError(f"corridor {corridor} and room sides {room}: at least 1, least <= largest")
    layout, hall = building_layout(rows, cols, rng, corridor=corridor, room=room)
    if not hall.any():
        least = 2 * room[1] + corridor + 4
        raise ValueError(
            f"a {rows}x{cols} plan has no corridor for the stairs and lifts: rooms on both "
            f"sides of a corridor need {least} rows or columns (2 x the largest room side, the "
            "corridor, the walls on either side of it and the outer walls)"
        )
    entrance = _entrance(hall)
    lifts, stairs = _cores(hall, entrance)
    plans = []
    for f in range(n_floors):
        free = layout.copy()
        doors(free, hall, loops, rng)
        arrival = entrance if f == 0 else lifts[0]
        rows_f = place(free, rng, start=arrival, n_goals=n_goals, avoid=[*lifts, *stairs])
        if f:  # the start is the ground floor's only
            r, c = arrival
            rows_f[r] = rows_f[r][:c] + FREE + rows_f[r][c + 1 :]
        plans.append(tuple(rows_f))
    floors = [
        Floor(f, "Ground floor" if f == 0 else f"Floor {f}", plans[f], f * STOREY_HEIGHT)
        for f in range(n_floors)
    ]
    every = range(n_floors)
    lift, stair = default_cost("lift", CELL_METRES), default_cost("stairs", CELL_METRES)
    ways = [
        Connection("lift", lift, tuple((f, r, c) for f in every), f"Lift {k}")
        for k, (r, c) in enumerate(lifts, start=1)
    ]
    ways += [
        Connection("stairs", stair, tuple((f, r, c) for f in every), f"Stairs {k}")
        for k, (r, c) in zip("AB", stairs, strict=True)
    ]
    return Building.from_parts(floors, ways, _names(plans, purpose, rng), name=name)


def _entrance(hall: BoolArray) -> Cell:
    """The corridor cell nearest the lower-left corner."""
    cells = np.argwhere(hall)
    r, c = cells[np.argmin(cells[:, 1] - cells[:, 0])]
    return int(r), int(c)


def _cores(hall: BoolArray, entrance: Cell) -> tuple[list[Cell], list[Cell]]:
    """The lift bank's cells (next to each other) and the two stairwells' (far apart): corridor
    cells, not the entrance; ``ValueError`` when the corridors have too few."""
    cells = [(int(r), int(c)) for r, c in np.argwhere(hall) if (int(r), int(c)) != entrance]
    if len(cells) < 3:
        raise ValueError(
            f"the corridors have {len(cells)} cell(s) beside the entrance: a building of several "
            "floors needs 3 for a lift and two stairs: give more rows and columns"
        )
    rows, cols = hall.shape
    middle = min(
        cells, key=lambda x: ((x[0] - (rows - 1) / 2) ** 2 + (x[1] - (cols - 1) / 2) ** 2, x)
    )
    lifts = [middle]
    corridors = set(cells)
    for _ in range(LIFTS - 1):  # the bank grows along the corridor
        nxt = [
            (r + dr, c + dc)
            for r, c in lifts
            for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0))
            if (r + dr, c + dc) in corridors and (r + dr, c + dc) not in lifts
        ]
        if nxt:
            lifts.append(nxt[0])
    rest = [x for x in cells if x not in lifts]

    def apart(a: Cell, b: Cell) -> int:
        return abs(a[0] - b[0]) + abs(a[1] - b[1])

    first = max(rest, key=lambda x: (min(apart(x, lift) for lift in lifts), x))
    second = max((x for x in rest if x != first), key=lambda x: (apart(x, first), x))
    return lifts, [first, second]


def _names(plans: list[tuple[str, ...]], purpose: str, rng: np.random.Generator) -> list[FloorName]:
    """A name for every goal, floor by floor: the purpose's list shuffled, then room numbers."""
    pool = [NAMES[purpose][i] for i in rng.permutation(len(NAMES[purpose]))]
    out = []
    for f, rows in enumerate(plans):
        goals = [(r, c) for r, row in enumerate(rows) for c, ch in enumerate(row) if ch == GOAL]
        for k, (r, c) in enumerate(goals, start=1):
            label = pool.pop() if pool else f"Room {f}.{k:02d}"
            out.append(FloorName(f, NamedCell(r, c, label)))
    return out
