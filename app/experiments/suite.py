"""The maps of ``experiment buildings`` and ``experiment visitors``: one floor or several.

A suite is made of, in this order:

* ``--buildings SIDE``: generated one-floor buildings (rooms along corridors, 8 destinations),
  SIDE x SIDE cells, each with its own seed (``--buildings 0``: none);
* ``--hospitals FxS``: generated hospitals of F floors of S x S cells each
  (:func:`app.domain.floorplans.generate_floors`: one plan on every floor, a lift bank and two
  stairwells, ``--hospital-goals`` named destinations a floor), each with its own seed;
* ``--imdf``: the project's IMDF venue, the three-level hospital of
  :mod:`app.mapio.imdf.sample`, written into a temporary folder and imported whole as
  ``maze import`` imports an IMDF archive without ``--level`` (every level a floor, its named
  destinations the goals);
* ``--mazes FILE`` (and ``--maze`` when it is not the shipped maze): map files, of one floor or
  several (:func:`app.domain.building.load_map_file` reads either kind).

A map of several floors is a :class:`~app.domain.building.Building`: six actions (``U`` and
``D`` the rides), distances in moves (a ride is one), an episode's steps counted in actions as
on one floor (a ride's time, :attr:`Building.durations`, is not counted). The KL the paper's
rule and goal-aware advice compare with kappa is in four actions' units on every map
(:func:`app.advice.models.kl_scale`), so their kappa levels mean the same here.
"""

from __future__ import annotations

import re
import tempfile
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any, Literal

import numpy as np

from app.arrays import IntArray
from app.domain.building import Building, Domain, load_map_file, n_floors
from app.domain.floorplans import generate_floors
from app.domain.generate import generate_building_domain
from app.domain.grid import GridDomain, bfs_distances_each, compass_detours_each
from app.domain.maps import DEFAULT_MAP
from app.experiments.common import rng_for

#: a hospital spec: floors x side (``3x64``)
HOSPITAL = re.compile(r"^\s*(\d+)\s*[xX]\s*(\d+)\s*$")
#: the generated hospitals' floors and side, at least and at most
FLOORS, SIDE = (2, 16), (32, 256)
Kind = Literal["building", "hospital", "venue", "file"]


@dataclass
class SuiteArgs:
    """The maps of the suite (the module's text says what each option adds)."""

    buildings: tuple[int, ...] = (64, 64, 128, 128)
    """Generated one-floor buildings: the side of each (rows = columns), each with its own
    seed (0 alone: none)."""
    hospitals: tuple[str, ...] = ()
    """Generated hospitals of several floors, FLOORSxSIDE each (e.g. 3x64: 3 floors of 64 x 64
    cells, the same plan on each, lifts and stairs), each with its own seed."""
    hospital_goals: int = 8
    """Named destinations on each floor of a generated hospital."""
    imdf: bool = False
    """Add the project's IMDF venue (app/mapio/imdf/sample.py's three-level hospital, imported
    whole as `maze import` does: every level a floor, its named destinations the goals)."""
    mazes: tuple[Path, ...] = ()
    """More maps of the suite: map files in the project's text format, of one floor or several
    (``maze import``, ``maze generate --floors``)."""

    def map_files(self) -> list[Path]:
        maze = Path(getattr(self, "maze", DEFAULT_MAP))
        extra = [maze] if maze != DEFAULT_MAP else []
        return [Path(p) for p in (*extra, *self.mazes)]

    def hospital_sizes(self) -> list[tuple[int, int]]:
        """(floors, side) of each ``--hospitals`` spec; ValueError names a bad one."""
        out = []
        for spec in self.hospitals:
            m = HOSPITAL.match(spec)
            if m is None:
                raise ValueError(
                    f"bad hospital {spec!r}: give FLOORSxSIDE, e.g. 3x64 (3 floors of 64 x 64)"
                )
            floors, side = int(m.group(1)), int(m.group(2))
            if not (FLOORS[0] <= floors <= FLOORS[1] and SIDE[0] <= side <= SIDE[1]):
                raise ValueError(
                    f"bad hospital {spec!r}: {FLOORS[0]}-{FLOORS[1]} floors of a side of "
                    f"{SIDE[0]}-{SIDE[1]} cells"
                )
            out.append((floors, side))
        return out

    def check_suite(self) -> None:
        """ValueError for a map the suite cannot make or find, or an empty suite."""
        if any(0 < b < 16 or b < 0 for b in self.buildings):
            raise ValueError("a generated building needs a side of at least 16 (0: none)")
        self.hospital_sizes()
        if not 1 <= self.hospital_goals <= 40:
            raise ValueError("hospital-goals must be 1 to 40 (destinations a floor)")
        if not (any(self.buildings) or self.hospitals or self.imdf or self.map_files()):
            raise ValueError(
                "the suite is empty: give --buildings sizes, --hospitals FxS, --imdf or --mazes"
            )
        for p in self.map_files():
            if not p.is_file():
                raise ValueError(f"no map file {p}")


@dataclass(frozen=True)
class MapSpec:
    index: int
    kind: Kind
    size: int  # the side of a generated map (0 otherwise)
    seed: int  # the generator's seed (-1 for a file or the venue)
    path: str  # the file ("" otherwise)
    floors: int = 1  # a generated hospital's floors (1 otherwise: see the map itself)
    goals: int = 8  # a generated hospital's destinations a floor

    @property
    def name(self) -> str:
        if self.kind == "file":
            return Path(self.path).stem
        if self.kind == "venue":
            return "imdf-hospital"
        if self.kind == "hospital":
            return f"hospital-{self.floors}x{self.size}-s{self.seed}"
        return f"building-{self.size}-s{self.seed}"


def map_suite(args: Any) -> list[MapSpec]:
    """The suite's maps in order (``args``: a :class:`SuiteArgs` with a ``seed``)."""
    out: list[MapSpec] = []
    for i, size in enumerate(args.buildings):  # the seeds of the one-floor suite as before
        if size:
            seed = int(rng_for(args.seed, "buildings-maps", i).integers(2**31))
            out.append(MapSpec(len(out), "building", size, seed, ""))
    for i, (floors, side) in enumerate(args.hospital_sizes()):
        seed = int(rng_for(args.seed, "buildings-hospitals", i).integers(2**31))
        out.append(MapSpec(len(out), "hospital", side, seed, "", floors, args.hospital_goals))
    if args.imdf:
        out.append(MapSpec(len(out), "venue", 0, -1, ""))
    for p in args.map_files():
        out.append(MapSpec(len(out), "file", 0, -1, str(p)))
    return out


def load_map(spec: MapSpec) -> Domain:
    if spec.kind == "file":
        return load_map_file(spec.path)
    if spec.kind == "venue":
        return imdf_hospital()
    if spec.kind == "hospital":
        rng = np.random.default_rng(spec.seed)
        return generate_floors(spec.size, spec.size, spec.floors, rng, purpose="hospital",
                               n_goals=spec.goals, name=spec.name)  # fmt: skip
    return generate_building_domain(spec.size, spec.size, spec.seed)


@cache
def imdf_hospital() -> Building:
    """The project's IMDF venue imported whole, as ``maze import`` imports an archive without
    ``--level`` (its default resolution, seed 0 for the start's ties)."""
    from app.mapio.budget import MemoryBudget
    from app.mapio.building import venue_building
    from app.mapio.imdf import DEFAULT_RESOLUTION, open_imdf
    from app.mapio.imdf.sample import hospital, write_archive

    with tempfile.TemporaryDirectory() as tmp:
        source = open_imdf(write_archive(hospital(), Path(tmp) / "hospital"))
        ordinals = [o for o, _ in source.levels]
        places = sum(source.places_on(o) for o in ordinals)
        budget = MemoryBudget(goals=max(MemoryBudget.goals, places), placed=len(ordinals))
        venue = source.venue(DEFAULT_RESOLUTION, budget=budget)
    made = venue_building(venue, np.random.default_rng(0), name="imdf-hospital").building
    if made is None:  # the sample's levels are joined by its lifts and stairs
        raise ValueError("the IMDF sample venue imported as one floor")
    return made


def goal_moves(domain: Domain) -> IntArray:
    """``out[g, s]``: the fewest actions from ``s`` to destination ``g`` (a ride is one)."""
    if isinstance(domain, GridDomain):
        return domain.goal_distances
    return bfs_distances_each(domain.next_state, domain.goals)


def compass_detours(domain: Domain) -> IntArray:
    """``out[g, s]``: the moves the bug would not make by itself on the way from ``s`` to
    destination ``g`` with fewest of them (on floors by the bug's rule there)."""
    if isinstance(domain, Building):
        return compass_detours_each(
            domain.next_state, domain.cells, domain.goals, takes=domain.compass_takes
        )
    return compass_detours_each(domain.next_state, domain.cells, domain.goals)


def plan_of(domain: Domain) -> dict[str, Any]:
    """What a map's table row says of its shape: floors, rows and columns, free cells."""
    rows, cols = domain.shape[-2:]
    return {"floors": n_floors(domain), "rows": rows, "cols": cols, "states": domain.n_states}
