"""Map files cannot exhaust the machine: ``python -m app maze import`` run as a user runs it, in
a process of its own under an address-space limit of 1 GiB, on the red team's files.

A 20,000 x 20,000 PNG (76 KB here, 400 million pixels) used 8.8 GiB and ended in a MemoryError
traceback after 86 s; a ROS YAML alias bomb never finished; the error for an image outside the
YAML's folder told whether that file exists. Each now ends in one line on stderr and exit 2."""

from __future__ import annotations

import os
import resource
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from app.mapio.budget import DEFAULT_MAX_MEMORY_MIB

REPO = Path(__file__).resolve().parents[2]
LIMIT = 1 << 30  # the import's address space: 1 GiB


def write_1bit_png(path: Path, width: int, height: int) -> Path:
    """A 1-bit grey PNG, white inside a black border, compressed row by row (no image of
    ``width`` x ``height`` is ever held here)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = struct.pack(">I", zlib.crc32(kind + data))
        return struct.pack(">I", len(data)) + kind + data + crc

    row = (width + 7) // 8
    edge = b"\x00" * (1 + row)  # filter byte 0, then the row's bits (0: black)
    inner = bytearray(b"\x00" + b"\xff" * row)
    inner[1] = 0x7F  # the left border
    inner[-1] = 0xFF << (8 * row - width + 1) & 0xFF  # the right border and the row's padding
    z = zlib.compressobj(9)
    body = [z.compress(edge)]
    body += [z.compress(bytes(inner)) for _ in range(height - 2)]
    body += [z.compress(edge), z.flush()]
    ihdr = struct.pack(">IIBBBBB", width, height, 1, 0, 0, 0, 0)
    data = chunk(b"IHDR", ihdr) + chunk(b"IDAT", b"".join(body)) + chunk(b"IEND", b"")
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + data)
    return path


def limited() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))


def import_map(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """``python -m app maze import ARGS`` under the 1 GiB address-space limit (numpy's BLAS on
    one thread: the address space its threads reserve grows with the cores, here 2)."""
    return subprocess.run(
        [sys.executable, "-m", "app", "maze", "import", *args],
        cwd=REPO,
        env=os.environ | {"OPENBLAS_NUM_THREADS": "1"},
        capture_output=True,
        text=True,
        timeout=timeout,
        preexec_fn=limited,
    )


def one_line_error(result: subprocess.CompletedProcess[str]) -> str:
    """The run's error: exit 2, nothing on stdout, one line on stderr, no traceback."""
    assert result.returncode == 2, result.stderr[-2000:]
    assert result.stdout == ""
    assert "Traceback" not in result.stderr and "MemoryError" not in result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr[-2000:]
    return lines[0]


def test_the_20000_by_20000_png_is_refused_from_its_header_within_1_gib(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    png = write_1bit_png(tmp_path / "huge.png", 20_000, 20_000)
    assert png.stat().st_size < 500_000
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", None)  # Pillow's own limit: 179 million
    with Image.open(png) as img:  # what the importer sees: a valid header
        assert img.size == (20_000, 20_000) and img.mode == "1"
    line = one_line_error(import_map(str(png), "--out", str(tmp_path / "huge.txt")))
    assert "a 20000 x 20000 pixel image (mode 1)" in line
    assert "would need about 209,062 MiB to import" in line
    assert f"more than the memory budget of {DEFAULT_MAX_MEMORY_MIB} MiB" in line
    assert "--max-memory MIB" in line
    assert not (tmp_path / "huge.txt").exists()
    # a ROS map naming it: the same refusal, naming the image
    (tmp_path / "huge.yaml").write_text(
        "image: huge.png\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\n"
        "free_thresh: 0.196\nnegate: 0\n"
    )
    line = one_line_error(import_map(str(tmp_path / "huge.yaml"), "--merge", "100"))
    assert f"{png}: a 20000 x 20000 pixel image (mode 1)" in line
    assert "at --merge 100" in line


def test_a_budget_above_what_the_process_may_have_still_ends_in_one_line(
    tmp_path: Path,
) -> None:
    """With the budget raised past the 1 GiB the process may have, the import starts decoding
    and runs out of memory: a one-line error, no MemoryError traceback."""
    png = write_1bit_png(tmp_path / "huge.png", 20_000, 20_000)
    line = one_line_error(import_map(str(png), "--max-memory", "100000", "--merge", "100"))
    assert "ran out of memory while importing it" in line
    assert "memory budget of 100000 MiB" in line


def test_under_the_limit_an_import_within_the_budget_succeeds(tmp_path: Path) -> None:
    """The limit leaves room for what the budget allows: a 4,000 x 4,000 plan (16 million
    pixels) merged 20 x 20, and a 300 x 300 one cell for cell."""
    big = write_1bit_png(tmp_path / "big.png", 4_000, 4_000)
    result = import_map(str(big), "--merge", "20", "--out", str(tmp_path / "big.txt"))
    assert result.returncode == 0, result.stderr
    assert "floor plan 4000x4000 pixels" in result.stdout
    assert "merged 20x20 pixels per cell: 200x200 cells" in result.stdout
    a = np.full((300, 300), 255, np.uint8)
    a[0, :] = a[-1, :] = a[:, 0] = a[:, -1] = 0
    Image.fromarray(a).save(tmp_path / "small.png")
    result = import_map(str(tmp_path / "small.png"), "--out", str(tmp_path / "small.txt"))
    assert result.returncode == 0, result.stderr
    assert "kept the largest connected region: 88804 of 88804 free cells" in result.stdout


def test_a_yaml_alias_bomb_is_refused_at_once_in_one_short_line(tmp_path: Path) -> None:
    bomb = 'a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n'
    for i in range(8):
        bomb += f"{chr(98 + i)}: &{chr(98 + i)} [" + ",".join([f"*{chr(97 + i)}"] * 9) + "]\n"
    f = tmp_path / "bomb.yaml"
    f.write_text(
        bomb + "image: *i\nresolution: *i\norigin: *i\noccupied_thresh: *i\n"
        "free_thresh: *i\nnegate: *i\n"
    )
    line = one_line_error(import_map(str(f), timeout=60))
    assert f"{f}: not a map_server YAML: line 1, column 4: anchors and aliases" in line
    assert len(line) - len(str(f)) < 130  # short (200 with the path it had), whatever the path


def test_an_image_outside_the_yaml_folder_is_one_message_whether_it_exists_or_not(
    tmp_path: Path,
) -> None:
    folder = tmp_path / "maps"
    folder.mkdir()
    Image.fromarray(np.full((5, 5), 254, np.uint8)).save(tmp_path / "outside.png")
    keys = "resolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\nfree_thresh: 0.2\n"
    f = folder / "m.yaml"
    f.write_text("image: ../outside.png\nnegate: 0\n" + keys)
    there = one_line_error(import_map(str(f)))
    (tmp_path / "outside.png").unlink()
    gone = one_line_error(import_map(str(f)))
    assert there == gone
    assert there == (
        f"error: {f}: image '../outside.png' is not inside the YAML file's folder ({folder}): "
        "only an image in that folder or below it is read"
    )


PEAK = """import runpy, sys
sys.argv = ["app", *sys.argv[1:]]
try:
    runpy.run_module("app", run_name="__main__")
except SystemExit as exc:
    assert not exc.code, exc.code
with open("/proc/self/status") as status:
    print(next(int(line.split()[1]) for line in status if line.startswith("VmHWM:")) * 1024)
"""


def peak_bytes(*args: str) -> int:
    """The peak RSS of ``python -m app maze import ARGS`` (its own: VmHWM, where ru_maxrss
    would count the parent's RSS at the fork)."""
    run = subprocess.run(
        [sys.executable, "-c", PEAK, "maze", "import", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        env=os.environ | {"OPENBLAS_NUM_THREADS": "1"},
    )
    assert run.returncode == 0, run.stderr[-2000:]
    return int(run.stdout.splitlines()[-1])


def test_an_import_takes_less_than_its_estimate(tmp_path: Path) -> None:
    """Peak RSS over a tiny import's, for an RGBA floor plan read cell for cell (the cells'
    cost) and a 1-bit one merged 40 x 40 (the pixels'): under the budget's estimate."""
    from app.mapio.budget import MemoryBudget

    out = str(tmp_path / "out.txt")
    tiny = write_1bit_png(tmp_path / "tiny.png", 40, 30)
    base = peak_bytes(str(tiny), "--out", out)
    a = np.full((400, 400, 4), 255, np.uint8)
    a[0, :] = a[-1, :] = a[:, 0] = a[:, -1] = (0, 0, 0, 255)
    Image.fromarray(a, "RGBA").save(tmp_path / "rgba.png")
    big = write_1bit_png(tmp_path / "big.png", 6_000, 6_000)
    budget = MemoryBudget()
    for args, estimate in [
        ([str(tmp_path / "rgba.png")], budget.image_estimate(400, 400, "RGBA", 1, alpha=True)),
        ([str(big), "--merge", "40"], budget.image_estimate(6_000, 6_000, "1", 40)),
    ]:
        took = peak_bytes(*args, "--out", out) - base
        assert 0 < took < estimate, (args, took, estimate)


def write_venue(path: Path, nx: int, ny: int, levels: int) -> Path:
    """An IMDF archive of ``levels`` levels, each ``ny`` rows of ``nx`` rooms of 8 x 8 m along
    corridors 2 m wide, a door each, a stairwell in the corner; four rooms named."""
    from app.mapio.imdf.sample import _box, _collection, _feature, fid, to_lonlat, write_archive

    width, depth = nx * 8.0, ny * 10.0
    level_features, units, openings = [], [], []
    for o in range(levels):
        level_id = fid("level", o)
        level_features.append(
            _feature("level", o, _box((0, 0, width, depth)), ordinal=o, name={"en": f"L{o}"})
        )
        for j in range(ny):
            y0 = j * 10.0
            corridor = (0.0, y0 + 8, width, y0 + 10)
            units.append(
                _feature("unit", f"{o}/c{j}", _box(corridor), category="walkway", level_id=level_id)
            )
            for i in range(nx):
                category = "stairs" if (i, j) == (0, 0) else "room"
                name = {"en": f"Room {i}.{j}"} if i == j < 4 else None
                box = (i * 8.0, y0, i * 8.0 + 8, y0 + 8)
                units.append(
                    _feature(
                        "unit",
                        f"{o}/{i}/{j}",
                        _box(box),
                        category=category,
                        level_id=level_id,
                        name=name,
                    )
                )
                line = [to_lonlat(i * 8 + 3.5, y0 + 8), to_lonlat(i * 8 + 4.5, y0 + 8)]
                geometry = {"type": "LineString", "coordinates": line}
                openings.append(_feature("opening", f"{o}/{i}/{j}", geometry, level_id=level_id))
    point = {"type": "Point", "coordinates": to_lonlat(20, 10)}
    docs = {
        "manifest.json": {"version": "1.0.0", "language": "en"},
        "venue.geojson": _collection(
            "venue", [_feature("venue", "v", _box((0, 0, width, depth)), display_point=point)]
        ),
        "level.geojson": _collection("level", level_features),
        "unit.geojson": _collection("unit", units),
        "opening.geojson": _collection("opening", openings),
    }
    return write_archive(docs, path)


def test_an_imdf_import_takes_less_than_its_estimate(tmp_path: Path) -> None:
    """Peak RSS over a tiny import's, for 3 levels of 800 x 500 cells (160 rooms a level, 4
    named: the goals), under the budget's estimate of the GeoJSON parsed and the venue drawn."""
    from app.mapio.budget import JSON_BYTE_COST, MemoryBudget, venue_cells

    out = str(tmp_path / "out.txt")
    tiny = write_venue(tmp_path / "tiny.zip", 2, 1, 1)
    base = peak_bytes(str(tiny), "--level", "0", "--out", out)
    big = write_venue(tmp_path / "big.zip", 20, 10, 3)
    n_bytes = sum(i.file_size for i in __import__("zipfile").ZipFile(big).infolist())
    budget = MemoryBudget()
    rows, cols = venue_cells(160.0, 100.0, 0.2)
    estimate = max(budget.venue_estimate(rows, cols, 3, n_bytes), n_bytes * JSON_BYTE_COST)
    took = peak_bytes(str(big), "--level", "1", "--resolution", "0.2", "--out", out) - base
    assert 0 < took < estimate, (took, estimate)


def test_an_imdf_venue_past_the_budget_is_refused_within_1_gib(tmp_path: Path) -> None:
    """A 160 x 100 m venue at 1 cm a cell (160 million cells a level) is refused from its
    extent, before anything is drawn, in one line."""
    big = write_venue(tmp_path / "big.zip", 20, 10, 3)
    line = one_line_error(import_map(str(big), "--level", "0", "--resolution", "0.01"))
    assert "would need about" in line and "give a coarser --resolution" in line
