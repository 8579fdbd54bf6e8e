"""``python -m app maze``: show, check, generate and import ASCII maps."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, NoReturn, cast

import numpy as np
import typer

from app.cli.building import describe_building, show_building
from app.domain.building import Building, load_map_file
from app.domain.grid import Frame, GridDomain, MapError, NamedCell, plain_names
from app.domain.maps import DEFAULT_MAP
from app.mapio.budget import DEFAULT_MAX_MEMORY_MIB

if TYPE_CHECKING:
    from app.arrays import BoolArray
    from app.mapio import Format, Imported
    from app.mapio.budget import MemoryBudget


class Kind(StrEnum):
    maze = "maze"
    building = "building"


class Purpose(StrEnum):
    hospital = "hospital"
    office = "office"


class ImportFormat(StrEnum):
    auto = "auto"
    movingai = "movingai"
    ros = "ros"
    image = "image"
    imdf = "imdf"


maze_cli = typer.Typer(help="Show, check, generate and import ASCII maps.", no_args_is_help=True)


def shown(path: Path) -> str:
    """How --help shows a default path: relative to the repository for the files shipped with
    the package (``app/domain/maps/default.txt``), else relative to here if it is below, else
    whole."""
    root = Path(__file__).resolve().parents[2]
    for base in (root, Path.cwd()):
        if path.is_absolute() and path.is_relative_to(base):
            return str(path.relative_to(base))
    return str(path)


MazeOption = Annotated[
    Path,
    typer.Option(
        "--maze",
        "-m",
        help="ASCII map file ('#' wall, '.' free, 'S', 'G').",
        show_default=shown(DEFAULT_MAP),
    ),
]


def load_any(path: Path) -> GridDomain | Building:
    """Load a map of one floor or several, or exit with the loader's message (which names
    the floor, line and column)."""
    try:
        return load_map_file(path)
    except MapError as exc:
        typer.echo(f"error: {path}: {exc}", err=True)
        raise typer.Exit(code=2) from None


def describe(domain: GridDomain) -> str:
    rows, cols = domain.shape
    dist = domain.goal_distances[:, domain.start]
    frame = ""
    if domain.frame is not None:
        ox, oy, yaw = domain.frame.origin
        frame = f", cells of {domain.frame.resolution:g} m, origin ({ox:g}, {oy:g}) m" + (
            f" yaw {yaw:g} rad" if yaw else ""
        )
    names = domain.goal_names or (None,) * len(domain.goals)
    goals = ", ".join(
        f"G{i}{list(domain.cell(g))}" + (f" {name!r}" if name else "") + f" at {int(d)}"
        for i, (g, name, d) in enumerate(zip(domain.goals, names, dist, strict=True))
    )
    return (
        f"{domain.name}: {rows}x{cols}, {domain.n_states} free cells, "
        f"{len(domain.dead_ends)} dead ends, start {list(domain.cell(domain.start))}{frame}\n"
        f"goals (shortest distance from start): {goals}"
    )


@maze_cli.command("show")
def maze_show(
    maze: Annotated[
        Path, typer.Argument(help="Map file.", show_default=shown(DEFAULT_MAP))
    ] = DEFAULT_MAP,
) -> None:
    """Print a map and what it contains (a map of several floors: each floor, its
    connections' stops marked by letter, and a legend)."""
    domain = load_any(maze)
    if isinstance(domain, Building):
        typer.echo(show_building(domain))
        typer.echo(describe_building(domain))
        return
    typer.echo(str(domain))
    typer.echo(describe(domain))


@maze_cli.command("check")
def maze_check(maze: Annotated[Path, typer.Argument(help="Map file to validate.")]) -> None:
    """Validate a map file (of one floor or several): exit 0 if it is a valid domain, 2 with
    the problem otherwise (its floor, line and column)."""
    domain = load_any(maze)
    said = describe_building(domain) if isinstance(domain, Building) else describe(domain)
    typer.echo(f"ok: {said}")


def _write(
    rows: list[str], out: Path | None, frame: Frame | None = None,
    names: Sequence[NamedCell] = (),
) -> None:  # fmt: skip
    name = out.stem if out is not None else "maze"
    domain = GridDomain.from_strings(rows, name=name, frame=frame, names=names)
    _emit(domain.to_text(), out, lambda: describe(domain))


def _write_building(building: Building, out: Path | None) -> None:
    _emit(building.to_text(), out, lambda: describe_building(building))


def _emit(text: str, out: Path | None, what: Callable[[], str]) -> None:
    """A map's text to ``out`` (saying what it wrote) or to standard output."""
    if out is None:
        typer.echo(text + "\n", nl=False)
        return
    out.write_text(text + "\n", encoding="utf-8")
    typer.echo(f"wrote {out}: {what()}")


def _fail(message: str) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code=2)


@maze_cli.command("generate")
def maze_generate(
    out: Annotated[Path | None, typer.Option(help="Write here (default: print).")] = None,
    kind: Annotated[
        Kind,
        typer.Option(help="maze: corridors one cell wide; building: rooms along corridors."),
    ] = Kind.maze,
    rows: Annotated[int, typer.Option(min=3, help="Rows, including walls.")] = 30,
    cols: Annotated[int, typer.Option(min=3, help="Columns, including walls.")] = 30,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    braid: Annotated[
        float,
        typer.Option(min=0.0, max=1.0, help="Mazes: 0 perfect; >0 opens dead ends (loops)."),
    ] = 0.0,
    corridor: Annotated[int, typer.Option(min=1, help="Buildings: corridor width in cells.")] = 2,
    room_min: Annotated[int, typer.Option(min=1, help="Buildings: least room side.")] = 3,
    room_max: Annotated[int, typer.Option(min=1, help="Buildings: largest room side.")] = 7,
    loops: Annotated[
        float,
        typer.Option(
            min=0.0, max=1.0, help="Buildings: chance of a second door between joined spaces."
        ),
    ] = 0.1,
    goals: Annotated[
        int, typer.Option(min=1, help="Number of goals (buildings of several floors: a floor).")
    ] = 8,
    floors: Annotated[
        int,
        typer.Option(
            min=1,
            help="Buildings: floors, the same plan on each, a lift bank and two stairwells "
            "at the same cells on every floor.",
        ),
    ] = 1,
    purpose: Annotated[
        Purpose,
        typer.Option(help="Buildings of several floors: what the destinations are named after."),
    ] = Purpose.office,
) -> None:
    """Generate a map: a maze (start lower-left, goals at corners and corridor ends) or a
    building (start at the corridor nearest the lower-left corner, goals in rooms; with
    --floors N, N floors joined by lifts and stairs, named destinations on each)."""
    from app.domain.floorplans import generate_floors
    from app.domain.generate import generate_building, generate_maze

    rng = np.random.default_rng(seed)
    if floors > 1 and kind is not Kind.building:
        _fail("--floors is for --kind building (a maze has one floor)")
    try:
        if floors > 1:
            name = out.stem if out is not None else "building"
            building = generate_floors(
                rows, cols, floors, rng, purpose=purpose.value, n_goals=goals,
                corridor=corridor, room=(room_min, room_max), loops=loops, name=name,
            )  # fmt: skip
            _write_building(building, out)
            return
        if kind is Kind.building:
            text = generate_building(
                rows,
                cols,
                rng,
                n_goals=goals,
                corridor=corridor,
                room=(room_min, room_max),
                loops=loops,
            )
        else:
            text = generate_maze(rows, cols, rng, braid=braid, n_goals=goals)
    except ValueError as exc:
        _fail(str(exc))
    _write(text, out)


@maze_cli.command("import")
def maze_import(
    file: Annotated[
        Path,
        typer.Argument(
            help="A Moving AI .map, a ROS map_server .yaml (with its image), a floor-plan "
            "image (.png, .pgm, ...) or an IMDF archive (a .zip or a folder)."
        ),
    ],
    out: Annotated[Path | None, typer.Option(help="Write the map here (default: print).")] = None,
    fmt: Annotated[
        ImportFormat,
        typer.Option("--format", help="The file's format (auto: by its name; a folder is IMDF)."),
    ] = ImportFormat.auto,
    merge: Annotated[
        int,
        typer.Option(
            min=1,
            help="Images: pixels per cell side. A cell is free when none of its pixels is "
            "occupied and at least half are free.",
        ),
    ] = 1,
    threshold: Annotated[
        int, typer.Option(min=1, max=255, help="Floor plans: grey level below which is wall.")
    ] = 128,
    seal: Annotated[
        int,
        typer.Option(
            min=0,
            help="Floor plans: close gaps in the outline up to 2*SEAL cells wide "
            "while finding the outside.",
        ),
    ] = 0,
    resolution: Annotated[
        float | None,
        typer.Option(
            min=0.01,
            help="IMDF: metres per cell side [default: 0.5].",
            show_default=False,
        ),
    ] = None,
    level: Annotated[
        int | None,
        typer.Option(
            help="IMDF: the ordinal of one level to import as a one-floor map (0 the ground "
            "or entrance level); without it, every level: a map of several floors.",
        ),
    ] = None,
    start: Annotated[
        str | None, typer.Option(help="Start cell ROW,COL of the imported grid (default: picked).")
    ] = None,
    goal_cells: Annotated[
        str | None, typer.Option(help='Goal cells "ROW,COL;ROW,COL" (default: --goals picked).')
    ] = None,
    goals: Annotated[
        int,
        typer.Option(
            min=1,
            help="How many goals to pick (spread out; rooms, dead ends); IMDF: the named "
            "destinations are the goals, picked only when there are none (a whole building: "
            "on each floor).",
        ),
    ] = 8,
    seed: Annotated[int, typer.Option(help="Random seed for the picks' ties.")] = 0,
    max_memory: Annotated[
        int,
        typer.Option(
            min=1,
            metavar="MIB",
            help="Memory the import may take, in MiB: estimated from the file's header "
            "(pixels and cells times what each step holds of them) and refused past it "
            "before anything is decoded.",
        ),
    ] = DEFAULT_MAX_MEMORY_MIB,
) -> None:
    """Import a map: keep its largest connected region, place a start and goals, write it as
    an ASCII map (with the resolution and origin when the format has them). An IMDF archive:
    every level, a map of several floors joined by its stairs and lifts (or one level with
    --level), its named destinations the goals."""
    from app.domain.place import largest_region, parse_cells, place
    from app.mapio import read_map
    from app.mapio.budget import MemoryBudget

    try:
        starts = parse_cells(start, "--start") if start is not None else [None]
        if len(starts) != 1:
            raise ValueError("--start takes one cell ROW,COL")
        goal_list = parse_cells(goal_cells, "--goal-cells") if goal_cells is not None else None
        budget = MemoryBudget.of_mib(max_memory, len(goal_list) if goal_list else goals)
        imdf = fmt is ImportFormat.imdf or (fmt is ImportFormat.auto and _looks_imdf(file))
        if imdf and level is None and (start is not None or goal_list is not None):
            raise ValueError(
                "--start and --goal-cells place one level's start and goals: give --level "
                "ORDINAL with them (a whole building's start is picked on its ground floor, its "
                "goals are its named destinations)"
            )
        if imdf:
            name = out.stem if out is not None else "building"
            read = _read_imdf(file, resolution, level, budget, goals, seed, name, out is None)
            if isinstance(read, Building):
                _write_building(read, out)
                return
            imported = read
        elif resolution is not None or level is not None:
            raise ValueError(
                "--resolution and --level are for IMDF archives (a ROS map has its own "
                "resolution; --merge makes coarser cells of an image)"
            )
        else:
            kind = cast("Format", fmt.value)  # not imdf here
            imported = read_map(
                file, kind, merge=merge, threshold=threshold, seal=seal, budget=budget
            )
        kept, dropped = largest_region(imported.free)
        named: dict[tuple[int, int], str] = {}
        if goal_list is None and imported.goals:
            named, outside = _named_goals(imported.goals, kept)
            if outside:
                shown = ", ".join(outside[:5]) + (
                    f" and {len(outside) - 5} more" if len(outside) > 5 else ""
                )
                imported.notes.append(
                    f"{len(outside)} destination(s) outside the kept region, left out: {shown}"
                )
        if named:
            goal_list = sorted(named)
        elif imdf and goal_list is None:
            imported.notes.append(
                f"no named destination in the kept region of this level: {goals} goal(s) picked"
            )
        rows = place(
            kept, np.random.default_rng(seed), start=starts[0], goals=goal_list, n_goals=goals
        )
        for note in imported.notes:
            typer.echo(note, err=out is None)
        total = int(imported.free.sum())
        typer.echo(
            f"kept the largest connected region: {total - dropped} of {total} free cells "
            f"({dropped} dropped)",
            err=out is None,
        )
        for i, cell in enumerate(sorted(named)):
            typer.echo(f"G{i} [{cell[0]}, {cell[1]}]: {named[cell]}", err=out is None)
        # the destinations' names go into the map as destination lines, made plain
        placed = [(r, c) for r, c in sorted(named) if rows[r][c] == "G"]
        written, changed = plain_names([(cell, named[cell]) for cell in placed])
        for note in changed:
            typer.echo(note, err=out is None)
        _write(rows, out, imported.frame, written)
    except ValueError as exc:  # MapError is one
        _fail(str(exc))
    except MemoryError:
        _fail(
            f"{file}: ran out of memory while importing it: the machine (or a limit on this "
            f"process) gave less than the memory budget of {max_memory} MiB; give a smaller "
            "--max-memory to be refused before decoding, or --merge K for fewer cells"
        )
    except OSError as exc:  # writing the map (the readers turn theirs into MapImportError)
        _fail(f"cannot write {out or 'the map'}: {exc.strerror or exc}")


def _looks_imdf(path: Path) -> bool:
    try:
        return path.is_dir() or path.suffix.lower() == ".zip"
    except OSError:
        return False


def _read_imdf(
    path: Path, resolution: float | None, level: int | None, budget: MemoryBudget,
    goals: int, seed: int, name: str, err: bool,
) -> Imported | Building:  # fmt: skip
    """An IMDF archive: one level (``level``, its ordinal) as a one-floor import, else the
    whole building (:func:`app.mapio.building.venue_building`), or the one-floor import of
    the one level its kept region lies on. A building's notes are printed here (on stderr when
    ``err``: the map goes to stdout)."""
    from app.mapio import MapImportError
    from app.mapio.budget import MemoryBudget
    from app.mapio.building import venue_building
    from app.mapio.imdf import DEFAULT_RESOLUTION, one_floor, open_imdf

    source = open_imdf(path, budget)
    listed = source.listed()
    if level is not None and level not in {o for o, _ in source.levels}:
        raise MapImportError(f"{path}: no level of ordinal {level}: the levels are {listed}")
    ordinals = [level] if level is not None else [o for o, _ in source.levels]
    # every named place may be a goal: the map's distances to each are budgeted
    places = sum(source.places_on(o) for o in ordinals)
    budget = MemoryBudget(budget.limit, max(budget.goals, places), len(ordinals))
    venue = source.venue(resolution or DEFAULT_RESOLUTION, budget=budget)
    notes: list[str] = []
    if level is None:
        stacked = venue_building(venue, np.random.default_rng(seed), n_goals=goals, name=name)
        if stacked.building is not None:
            b = stacked.building
            shown = ", ".join(f"{f.label}" for f in b.floors[:12])
            head = f"IMDF venue {venue.name!r}: {b.n_floors} floors ({shown})"
            for note in [head, *venue.notes, *stacked.notes]:
                typer.echo(note, err=err)
            for i, g in enumerate(b.goals):
                typer.echo(f"G{i} {list(b.cell(g))}: {b.goal_label(i)}", err=err)
            return b
        level, notes = stacked.ordinal, stacked.notes
    assert level is not None
    imported = one_floor(venue, level)
    imported.notes.extend(notes)
    return imported


def _named_goals(
    goals: list[tuple[tuple[int, int], str]], kept: BoolArray
) -> tuple[dict[tuple[int, int], str], list[str]]:
    """The named cells in the kept region (the names of one cell joined with " / "), and the
    names of the others."""
    named: dict[tuple[int, int], str] = {}
    outside: list[str] = []
    for cell, name in goals:
        if not kept[cell]:
            outside.append(repr(name))
        else:
            named[cell] = f"{named[cell]} / {name}" if cell in named else name
    return named, outside
