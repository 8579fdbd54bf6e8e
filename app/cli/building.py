"""What ``maze check`` and ``maze show`` print of a map of several floors: a summary, and each
floor drawn under its title, each connection's stops marked with its letter, and a legend."""

from __future__ import annotations

from app.domain.building import Building
from app.domain.grid import FREE

#: the letters that mark connections' stops, in the connections' order (not S and G, which
#: are the start and the goals); connections beyond them are marked with MORE
LETTERS = "ABCDEFHIJKLMNOPQRTUVWXYZabcdefhijklmnopqrtuvwxyz"
MORE = "*"


def letter(index: int) -> str:
    return LETTERS[index] if index < len(LETTERS) else MORE


def describe_building(b: Building) -> str:
    """One line on the building, one on its goals (with the fewest moves of time to each from
    the start: :meth:`Building.times_to`)."""
    floors, rows, cols = b.shape
    frame = f", cells of {b.frame.resolution:g} m" if b.frame is not None else ""
    times = b.times_to(b.start)
    start = b.cell(b.start)
    names = b.goal_names or (None,) * len(b.goals)
    goals = ", ".join(
        f"G{i}{list(b.cell(g))}" + (f" {name!r}" if name else "") + f" at {int(times[g])}"
        for i, (g, name) in enumerate(zip(b.goals, names, strict=True))
    )
    ordinals = f"ordinals {b.floors[0].ordinal} to {b.floors[-1].ordinal}"
    return (
        f"{b.name}: {floors} floors of {rows}x{cols} ({ordinals}), {b.n_states} free cells, "
        f"{len(b.connections)} connection(s), start {list(start)} on floor "
        f"{b.floors[start[0]].label}{frame}\n"
        f"goals (fewest moves of time from the start, rides included): {goals}"
    )


def show_building(b: Building) -> str:
    """Every floor, lowest first, titled by its ordinal and name (and its index in the cells,
    and its elevation), the connections' stops marked by their letters; then the legend."""
    marks = {}
    for i, conn in enumerate(b.connections):
        for f, r, c in conn.stops:
            if b.floors[f].rows[r][c] == FREE:  # the start and goals stay in sight
                marks[int(b.state_of[f, r, c])] = letter(i)
    parts = []
    for f, floor in enumerate(b.floors):
        height = f", elevation {floor.elevation:g} m" if floor.elevation is not None else ""
        parts.append(f"floor {floor.label} (floor {f} of the cells{height})")
        parts.append(b.render(f, marks))
        parts.append("")
    parts.append(legend(b))
    return "\n".join(parts)


def legend(b: Building) -> str:
    """A line per connection: its letter, kind, name, cost and stops."""
    if not b.connections:
        return "no connection between the floors"
    out = []
    for i, conn in enumerate(b.connections):
        cells = {(r, c) for _, r, c in conn.stops}
        ordinals = [b.floors[f].ordinal for f in conn.floors]
        if len(cells) == 1:
            r, c = next(iter(cells))
            where = f"floors {', '.join(map(str, ordinals))} at [{r}, {c}]"
        else:
            where = " ".join(
                f"{o}:[{r}, {c}]" for o, (_, r, c) in zip(ordinals, conn.stops, strict=True)
            )
        out.append(f"{letter(i)}  {conn.kind} {conn.name!r}, {conn.cost} moves a floor: {where}")
    if len(b.connections) > len(LETTERS):
        out.append(f"({MORE} marks every connection after the {len(LETTERS)}th)")
    return "\n".join(out)
