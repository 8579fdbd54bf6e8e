"""Importing Moving AI maps, ROS map_server maps and floor-plan images."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image
from typer.testing import CliRunner

from app.cli import cli
from app.domain.grid import GridDomain
from app.mapio import MapImportError, read_map
from app.mapio.image import outside
from app.mapio.movingai import parse_movingai
from app.mapio.raster import merge_cells

runner = CliRunner()

MOVINGAI = """type octile
height 6
width 10
map
@@@@@@@@@@
@..GS.T..@
@.@@@@@@.@
@.@..@@@.@
@....WW..@
@@@@@@@@@@
"""


def test_movingai_terrain_g_and_s_are_passable_ground(tmp_path: Path) -> None:
    f = tmp_path / "a.map"
    f.write_text(MOVINGAI)
    got = read_map(f)
    assert got.frame is None
    assert got.free.shape == (6, 10)
    assert got.free[1, 3] and got.free[1, 4]  # G and S: ground and swamp
    assert not got.free[1, 6] and not got.free[4, 5]  # T and W block
    assert int(got.free.sum()) == 19


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("type octile\nheight 2\nwidth 2\n..\n..", "line 4: expected .* or .map. before the rows"),
        ("type octile\nheight 2\nwidth 2", "no .map. line"),
        ("type octile\nwidth 2\nmap\n..\n..", "no 'height' line"),
        ("type octile\nheight two\nwidth 2\nmap\n..", "height 'two' is not a positive"),
        ("type hex\nheight 1\nwidth 2\nmap\n..", "only 'type octile'"),
        ("type octile\nheight 3\nwidth 2\nmap\n..\n..", "height 3, the map has 2 rows"),
        ("type octile\nheight 2\nwidth 2\nmap\n..\n...", "line 6: 3 characters where"),
        ("type octile\nheight 2\nwidth 2\nmap\n..\n.x", "line 6, column 2: unknown terrain 'x'"),
        ("hello\nmap\n", "line 1: expected 'type octile'"),
    ],
)
def test_movingai_errors_name_the_problem(text: str, message: str) -> None:
    with pytest.raises(MapImportError, match=message):
        parse_movingai(text.splitlines(), "x.map")


def _ros(tmp_path: Path, img: np.ndarray, **meta: object) -> Path:
    Image.fromarray(img).save(tmp_path / "m.pgm")
    values: dict[str, object] = {
        "image": "m.pgm",
        "resolution": 0.05,
        "origin": [-1.5, 2.0, 0.0],
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
        "negate": 0,
    } | meta
    lines = [f"{k}: {v}" for k, v in values.items() if v is not None]
    f = tmp_path / "m.yaml"
    f.write_text("\n".join(lines) + "\n")
    return f


def test_ros_map_reads_thresholds_origin_and_merges(tmp_path: Path) -> None:
    img = np.full((7, 9), 205, np.uint8)  # unknown
    img[1:6, 1:8] = 254  # free
    img[3, 4] = 0  # occupied
    got = read_map(_ros(tmp_path, img))
    assert got.frame is not None and got.frame.resolution == 0.05
    assert got.frame.origin == (-1.5, 2.0, 0.0)
    assert int(got.free.sum()) == 5 * 7 - 1 and not got.free[3, 4] and not got.free[0, 0]
    # negate: black means free
    neg = read_map(_ros(tmp_path, 255 - img, negate=1))
    assert (neg.free == got.free).all()
    merged = read_map(_ros(tmp_path, img), merge=2)
    assert merged.frame is not None and merged.frame.resolution == pytest.approx(0.1)
    assert merged.free.shape == (4, 5)  # padded at the top and right, aligned to the origin
    assert (merged.free == merge_cells(img == 254, img == 0, 2)).all()


def test_ros_origin_is_the_lower_left_pixel(tmp_path: Path) -> None:
    img = np.full((6, 8), 254, np.uint8)
    f = _ros(tmp_path, img, resolution=0.5, origin=[10.0, 20.0, 0.0])
    cli_out = tmp_path / "out.txt"
    result = runner.invoke(cli, ["maze", "import", str(f), "--out", str(cli_out), "--merge", "2"])
    assert result.exit_code == 0, result.output
    d = GridDomain.from_file(cli_out)
    assert d.frame is not None and d.frame.resolution == 1.0
    # pixel (row 5 from the top, col 0) is the lower-left one: its centre is origin + 0.25 m
    assert d.frame.cell_at(10.25, 20.25, d.shape[0]) == (d.shape[0] - 1, 0)
    assert d.frame.cell_at(13.9, 22.9, d.shape[0]) == (0, 3)


@pytest.mark.parametrize(
    ("meta", "message"),
    [
        ({"resolution": None}, "missing key.*resolution"),
        ({"resolution": "fast"}, "resolution must be a number"),
        ({"resolution": -1}, "resolution must be positive"),
        ({"origin": "[1, 2]"}, r"origin must be \[x, y, yaw\]"),
        ({"free_thresh": 0.9}, "free_thresh <= occupied_thresh"),
        ({"negate": 3}, "negate must be 0 or 1"),
        ({"mode": "fancy"}, "mode 'fancy'"),
        ({"image": "nowhere.pgm"}, "image 'nowhere.pgm' not found"),
    ],
)
def test_ros_errors_name_the_key(tmp_path: Path, meta: dict[str, object], message: str) -> None:
    f = _ros(tmp_path, np.full((3, 3), 254, np.uint8), **meta)
    with pytest.raises(MapImportError, match=message):
        read_map(f)


def test_ros_yaml_and_image_that_are_not_what_they_say(tmp_path: Path) -> None:
    f = tmp_path / "bad.yaml"
    f.write_text("image: [unclosed\n")
    with pytest.raises(MapImportError, match="not a YAML file"):
        read_map(f)
    f.write_text("- a list\n")
    with pytest.raises(MapImportError, match="mapping of keys"):
        read_map(f)
    (tmp_path / "m.pgm").write_bytes(b"not an image at all")
    f = tmp_path / "m.yaml"
    f.write_text(
        "image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\noccupied_thresh: 0.65\n"
        "free_thresh: 0.2\nnegate: 0\n"
    )
    with pytest.raises(MapImportError, match="not an image that can be read"):
        read_map(f)


def _plan(gap: int) -> np.ndarray:
    """A white page with a black outline (an entrance ``gap`` pixels wide) and a room wall."""
    p = np.full((30, 40), 255, np.uint8)
    p[5, 5:35] = p[25, 5:35] = 0
    p[5:26, 5] = p[5:26, 34] = 0
    p[25, 15 : 15 + gap] = 255
    p[5:26, 20] = 0
    p[12:15, 20] = 255  # an inner door
    return p


def test_floor_plan_drops_the_outside(tmp_path: Path) -> None:
    f = tmp_path / "plan.png"
    Image.fromarray(_plan(0)).save(f)
    got = read_map(f)
    assert int(got.free.sum()) == 19 * 27 + 3  # the inside: two rooms and the inner door
    assert not got.free[0, 0] and got.free[10, 10]


def test_floor_plan_entrance_is_sealed_on_request(tmp_path: Path) -> None:
    f = tmp_path / "plan.png"
    Image.fromarray(_plan(3)).save(f)
    with pytest.raises(MapImportError, match="try --seal"):
        read_map(f)
    got = read_map(f, seal=2)
    assert got.free[10, 10] and not got.free[0, 0]
    assert got.free[25, 16]  # the entrance stays open
    assert not got.free[28, 16]  # the street outside it is gone


def test_floor_plan_transparent_pixels_are_outside(tmp_path: Path) -> None:
    rgba = np.zeros((10, 10, 4), np.uint8)  # all transparent
    rgba[2:8, 2:8] = (255, 255, 255, 255)
    f = tmp_path / "t.png"
    Image.fromarray(rgba, "RGBA").save(f)
    got = read_map(f)
    assert int(got.free.sum()) == 36


def slow_merge(free: np.ndarray, blocked: np.ndarray, k: int) -> np.ndarray:
    h, w = free.shape
    rows, cols = -(-h // k), -(-w // k)
    out = np.zeros((rows, cols), dtype=bool)
    for r in range(rows):
        for c in range(cols):
            # cell r counts from the top; the bottom cell ends at the last pixel row
            top = h - (rows - r) * k
            f = b = 0
            for i in range(top, top + k):
                for j in range(c * k, c * k + k):
                    if 0 <= i < h and j < w:
                        f += bool(free[i, j] and not blocked[i, j])
                        b += bool(blocked[i, j])
            out[r, c] = b == 0 and 2 * f >= k * k
    return out


@settings(max_examples=150, deadline=None)
@given(st.integers(1, 12), st.integers(1, 12), st.integers(1, 5), st.integers(0, 2**31))
def test_merge_matches_the_slow_version(h: int, w: int, k: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    blocked = rng.random((h, w)) < 0.1
    free = (rng.random((h, w)) < 0.8) & ~blocked
    assert (merge_cells(free, blocked, k) == slow_merge(free, blocked, k)).all()


@settings(max_examples=80, deadline=None)
@given(st.integers(3, 14), st.integers(3, 14), st.integers(0, 2**31))
def test_outside_is_what_touches_the_border(h: int, w: int, seed: int) -> None:
    free = np.random.default_rng(seed).random((h, w)) < 0.6
    out = outside(free)
    # slow: flood fill from every free border cell
    seen = set()
    stack = [
        (r, c)
        for r in range(h)
        for c in range(w)
        if free[r, c] and (r in (0, h - 1) or c in (0, w - 1))
    ]
    while stack:
        r, c = stack.pop()
        if (r, c) in seen:
            continue
        seen.add((r, c))
        for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            nr, nc = r + dr, c + dc
            if 0 <= nr < h and 0 <= nc < w and free[nr, nc]:
                stack.append((nr, nc))
    assert {tuple(map(int, x)) for x in np.argwhere(out)} == seen


def test_unknown_format_and_missing_file_are_named(tmp_path: Path) -> None:
    with pytest.raises(MapImportError, match="no such file"):
        read_map(tmp_path / "none.map")
    f = tmp_path / "plan.dwg"
    f.write_text("x")
    with pytest.raises(MapImportError, match="give --format"):
        read_map(f)
    with pytest.raises(MapImportError, match="merge must be at least 1"):
        read_map(f, "image", merge=0)


def test_cli_import_writes_a_checked_map_and_says_what_it_dropped(tmp_path: Path) -> None:
    f = tmp_path / "a.map"
    f.write_text(MOVINGAI)
    out = tmp_path / "a.txt"
    result = runner.invoke(cli, ["maze", "import", str(f), "--out", str(out), "--goals", "2"])
    assert result.exit_code == 0, result.output
    assert "13 of 19 free cells (6 dropped)" in result.output
    assert "wrote" in result.output and "goals (shortest distance from start)" in result.output
    d = GridDomain.from_file(out)
    assert d.n_states == 13 and len(d.goals) == 2
    check = runner.invoke(cli, ["maze", "check", str(out)])
    assert check.exit_code == 0
    placed = runner.invoke(
        cli,
        ["maze", "import", str(f), "--out", str(out), "--start", "1,1", "--goal-cells", "4,4;3,3"],
    )
    assert placed.exit_code == 0, placed.output
    d = GridDomain.from_file(out)
    assert d.cell(d.start) == (1, 1) and [d.cell(g) for g in d.goals] == [(3, 3), (4, 4)]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--start", "1,8"], r"start \[1, 8\] is a wall or outside the kept region"),
        (["--start", "1;2"], "write a cell as ROW,COL"),
        (["--start", "1,1;2,1"], "--start takes one cell"),
        (["--goal-cells", "0,0"], r"goal \[0, 0\] is a wall"),
        (["--goals", "13"], "do not fit in 13 free cells"),
    ],
)
def test_cli_import_refuses_bad_placements(tmp_path: Path, args: list[str], message: str) -> None:
    f = tmp_path / "a.map"
    f.write_text(MOVINGAI)
    result = runner.invoke(cli, ["maze", "import", str(f), *args])
    assert result.exit_code == 2
    assert message in result.output or __import__("re").search(message, result.output)


def test_cli_generate_building(tmp_path: Path) -> None:
    out = tmp_path / "b.txt"
    args = ["maze", "generate", "--kind", "building", "--rows", "40", "--cols", "50"]
    result = runner.invoke(cli, [*args, "--out", str(out), "--seed", "3"])
    assert result.exit_code == 0, result.output
    d = GridDomain.from_file(out)
    assert d.shape == (40, 50) and len(d.goals) == 8
    again = runner.invoke(cli, [*args, "--seed", "3"])
    assert again.output.strip() == out.read_text().strip()
