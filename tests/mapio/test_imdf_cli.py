"""``maze import`` of an IMDF archive: one level as a one-floor map, its destinations the
goals, the frame in the header; refused without --level."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from app.cli import cli
from app.domain.grid import GridDomain
from app.mapio.imdf.sample import LAT0, LON0
from app.mapio.venue import LocalProjection
from tests.mapio.imdf_helpers import docs, features, write

runner = CliRunner()


def test_cli_import_imdf_an_unknown_level_lists_the_levels(tmp_path: Path) -> None:
    path = write(tmp_path)
    other = runner.invoke(cli, ["maze", "import", str(path), "--level", "5"])
    assert other.exit_code == 2
    assert "Traceback" not in other.output
    assert (
        "no level of ordinal 5: the levels are 0 (Ground floor), 1 (First floor), 2 (Second floor)"
    ) in " ".join(other.output.split())


@pytest.mark.parametrize("zipped", [True, False], ids=["zip", "folder"])
def test_cli_import_imdf_level_writes_its_destinations_as_named_goals(
    tmp_path: Path, zipped: bool
) -> None:
    path = write(tmp_path, zipped=zipped)
    out = tmp_path / "ground.txt"
    result = runner.invoke(cli, ["maze", "import", str(path), "--level", "0", "--out", str(out)])
    assert result.exit_code == 0, result.output
    text = out.read_text()
    assert text.startswith("resolution: 0.5\norigin: ")
    d = GridDomain.from_file(out)
    assert d.frame is not None and d.frame.resolution == 0.5
    # the ground floor's destinations; the store (no door) is not in the kept region
    listed = [line for line in result.output.splitlines() if line.startswith("G")]
    names = [line.split(": ", 1)[1] for line in listed]
    assert sorted(names) == sorted(
        ["Radiology", "Emergency", "Pharmacy", "Information", "Registration"]
    )
    assert len(d.goals) == 5
    for i, g in enumerate(d.goals):  # listed in the written map's order, G0 first
        assert listed[i].startswith(f"G{i} [{d.cell(g)[0]}, {d.cell(g)[1]}]: ")
    # the map keeps their names: destination lines of its header
    assert d.goal_names == tuple(names)
    assert text.count("\ndestination: ") == 5
    assert "1 destination(s) outside the kept region, left out: 'Store'" in result.output
    assert "elevator 'Lift 1' to level(s) 1, 2" in result.output
    assert d.start not in d.goals


def test_cli_import_imdf_positions_snap_to_the_destinations_cells(tmp_path: Path) -> None:
    out = tmp_path / "first.txt"
    args = ["maze", "import", str(write(tmp_path)), "--level", "1", "--out", str(out)]
    result = runner.invoke(cli, args)
    assert result.exit_code == 0, result.output
    d = GridDomain.from_file(out)
    goal_names = {
        line.split(": ", 1)[1]: line.split(" ", 1)[1].split("]")[0] + "]"
        for line in result.output.splitlines()
        if line.startswith("G")
    }
    p = LocalProjection(LON0, LAT0)
    anchors = {a["id"]: a for a in features(docs(), "anchor")}
    first = [
        o
        for o in features(docs(), "occupant")
        if o["properties"]["name"]["en"] in ("Cardiology", "Dermatology", "Laboratory")
    ]
    assert len(first) == 3
    for occupant in first:
        lon, lat = anchors[occupant["properties"]["anchor_id"]]["geometry"]["coordinates"]
        state = d.state_at(*p.to_xy(lon, lat))  # metres of the written map's frame
        r, c = d.cell(state)
        assert state in d.goals
        assert goal_names[occupant["properties"]["name"]["en"]] == f"[{r}, {c}]"


def test_cli_import_imdf_options(tmp_path: Path) -> None:
    path = write(tmp_path, zipped=False)
    coarse = runner.invoke(
        cli, ["maze", "import", str(path), "--format", "imdf", "--level", "2", "--resolution", "1"]
    )
    assert coarse.exit_code == 0, coarse.output
    assert coarse.stdout.startswith("resolution: 1.0\n")  # the map on stdout, notes on stderr
    placed = runner.invoke(
        cli,
        ["maze", "import", str(path), "--level", "2", "--goal-cells", "10,12", "--start", "11,12"],
    )
    assert placed.exit_code == 0, placed.output
    assert "G0 [" not in placed.output  # cells given: no named goals
    plain = tmp_path / "a.map"
    plain.write_text("type octile\nheight 1\nwidth 3\nmap\n...\n")
    for option in (["--level", "0"], ["--resolution", "0.5"]):
        refused = runner.invoke(cli, ["maze", "import", str(plain), *option])
        assert refused.exit_code == 2
        assert "--resolution and --level are for IMDF archives" in refused.output


def test_cli_import_imdf_bad_archive_is_one_line(tmp_path: Path) -> None:
    d = docs()
    features(d, "unit")[0]["properties"]["level_id"] = "nowhere"
    result = runner.invoke(cli, ["maze", "import", str(write(tmp_path, d)), "--level", "0"])
    assert result.exit_code == 2
    assert result.output.count("\n") == 1 and result.output.startswith("error: ")
    assert "level_id 'nowhere' is not a feature of level.geojson" in result.output
    small = runner.invoke(
        cli, ["maze", "import", str(write(tmp_path)), "--level", "0", "--max-memory", "1"]
    )
    assert small.exit_code == 2 and "more than the memory budget of 1 MiB" in small.output


def test_cli_import_imdf_many_levels_are_listed_short(tmp_path: Path) -> None:
    d = docs()
    ground = features(d, "level")[0]
    for o in range(3, 21):  # empty levels above: 21 in all
        props = ground["properties"] | {"ordinal": o, "name": {"en": f"Level {o}"}}
        features(d, "level").append({**ground, "id": f"level-{o}", "properties": props})
    result = runner.invoke(cli, ["maze", "import", str(write(tmp_path, d)), "--level", "99"])
    assert result.exit_code == 2
    assert "11 (Level 11) and 9 more" in " ".join(result.output.split())
    assert len(result.output) < 500


def test_cli_import_imdf_level_without_destinations_picks_goals(tmp_path: Path) -> None:
    d = docs()
    for name in ("occupant", "anchor", "amenity"):
        d[f"{name}.geojson"]["features"] = []
    for unit in features(d, "unit"):
        unit["properties"]["name"] = None
    out = tmp_path / "plain.txt"
    args = ["maze", "import", str(write(tmp_path, d)), "--level", "2", "--goals", "3"]
    result = runner.invoke(cli, [*args, "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "no named destination in the kept region of this level: 3 goal(s) picked" in (
        result.output
    )
    assert len(GridDomain.from_file(out).goals) == 3
