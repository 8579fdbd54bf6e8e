"""Map imports within a memory budget, hostile map files refused in one short line.

Each importer estimates what its import will hold from the file's header (an image's size and
mode, a Moving AI map's height and width) and refuses past the budget before decoding; a ROS
YAML is read without anchors or aliases, only up to 64 KiB, and may name only an image in its
own folder; values quoted in errors are cut short."""

from __future__ import annotations

import struct
import time
import zlib
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from PIL import Image
from typer.testing import CliRunner

from app.cli import cli
from app.domain.grid import GridDomain
from app.mapio import MapImportError, raster, read_map, shorten
from app.mapio.budget import DEFAULT_MAX_MEMORY_MIB, MemoryBudget, decoded_bytes
from app.mapio.raster import read_image

runner = CliRunner()

ROS_KEYS = "resolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"


def png_header_only(path: Path, width: int, height: int, depth: int = 1) -> Path:
    """A PNG of a grey ``width`` x ``height`` image with no pixel data at all: only a reader
    that stops at the header gets anywhere with it."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = struct.pack(">I", zlib.crc32(kind + data))
        return struct.pack(">I", len(data)) + kind + data + crc

    ihdr = struct.pack(">IIBBBBB", width, height, depth, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b""))
    return path


def framed(height: int, width: int) -> npt.NDArray[np.uint8]:
    """White with a black outline: a floor plan whose inside is all floor."""
    a = np.full((height, width), 255, np.uint8)
    a[0, :] = a[-1, :] = a[:, 0] = a[:, -1] = 0
    return a


def ros_yaml(folder: Path, image: str, extra: str = "negate: 0\n") -> Path:
    f = folder / "m.yaml"
    f.write_text(f"image: {image}\n{ROS_KEYS}{extra}")
    return f


def refusal(path: Path, **kw: object) -> str:
    with pytest.raises(MapImportError) as info:
        read_map(path, **kw)  # type: ignore[arg-type]
    message = str(info.value)
    assert "\n" not in message
    return message


# ---- the budget ---------------------------------------------------------------------------


def test_an_image_past_the_budget_is_refused_from_its_header_before_decoding(
    tmp_path: Path,
) -> None:
    """The PNG has no pixel data: a reader that decoded it would say so; the budget refuses it
    from its size and mode alone, naming them, the estimate, the budget and the option."""
    f = png_header_only(tmp_path / "huge.png", 20_000, 20_000)
    message = refusal(f)
    assert "a 20000 x 20000 pixel image (mode 1)" in message
    assert f"more than the memory budget of {DEFAULT_MAX_MEMORY_MIB} MiB" in message
    assert "would need about 209,062 MiB" in message  # 400M cells x 544 bytes, 400M pixels x 4
    assert "--max-memory MIB" in message
    assert "at --merge 1," in message
    assert "pixels a cell with --merge" not in message  # one cell too: 400M pixels x 4 bytes
    # the same refusal for a ROS map naming such an image
    assert f"{tmp_path / 'huge.png'}: a 20000 x 20000" in refusal(ros_yaml(tmp_path, "huge.png"))


def test_the_budget_is_what_the_option_says_and_a_merge_that_fits_is_suggested(
    tmp_path: Path,
) -> None:
    f = tmp_path / "plan.png"
    Image.fromarray(framed(1000, 1000)).save(f)
    message = refusal(f, budget=MemoryBudget.of_mib(30))
    assert "a 1000 x 1000 pixel image (mode L)" in message and "of 30 MiB" in message
    suggested = int(message.rsplit("--merge ", 1)[1])
    assert suggested > 1
    read_map(f, merge=suggested, budget=MemoryBudget.of_mib(30))  # fits, as suggested
    refusal(f, merge=suggested - 1, budget=MemoryBudget.of_mib(30))
    # through the CLI: the option, and exit 2 with the one line
    out = tmp_path / "plan.txt"
    refused = runner.invoke(cli, ["maze", "import", str(f), "--max-memory", "30"])
    assert refused.exit_code == 2
    assert refused.output.startswith("error: ") and refused.output.count("\n") == 1
    assert "memory budget of 30 MiB" in refused.output
    args = ["maze", "import", str(f), "--out", str(out), "--merge", str(suggested)]
    done = runner.invoke(cli, [*args, "--max-memory", "30"])
    assert done.exit_code == 0, done.output
    assert GridDomain.from_file(out).n_states > 0


def test_more_goals_need_more_memory() -> None:
    few, many = MemoryBudget(goals=8), MemoryBudget(goals=1000)
    assert few.cell_bytes == MemoryBudget(goals=1).cell_bytes
    assert many.cell_bytes > few.cell_bytes
    assert many.image_estimate(500, 500, "L", 1) > few.image_estimate(500, 500, "L", 1)


@pytest.mark.parametrize("mode", ["1", "L", "P", "RGB", "RGBA", "LA", "I;16", "I", "F", "CMYK"])
def test_pillows_limit_while_decoding_follows_the_budget(mode: str) -> None:
    """Pillow's decompression-bomb limit is the budget's pixels at the cheapest: no image
    Pillow would let through has an import the budget allows, in any mode, at any merge."""
    budget = MemoryBudget.of_mib(64)
    side = int(np.sqrt(budget.max_pixels)) + 1
    for merge in (1, 10, side):
        assert budget.image_estimate(side, side, mode, merge) > budget.limit
    assert decoded_bytes(mode) in (1, 2, 4)


def test_pillows_limit_is_put_back_after_a_read(tmp_path: Path) -> None:
    f = tmp_path / "plan.png"
    Image.fromarray(framed(20, 20)).save(f)
    before = Image.MAX_IMAGE_PIXELS
    read_map(f)
    refusal(png_header_only(tmp_path / "huge.png", 30_000, 30_000))
    assert before == Image.MAX_IMAGE_PIXELS


def test_a_moving_ai_map_past_the_budget_is_refused_from_its_header(tmp_path: Path) -> None:
    f = tmp_path / "big.map"
    f.write_text("type octile\nheight 100000\nwidth 100000\nmap\n....\n")
    message = refusal(f)
    assert "a 100000 x 100000 map would need about" in message
    assert f"memory budget of {DEFAULT_MAX_MEMORY_MIB} MiB" in message and "--max-memory" in message
    f.write_text("type octile\nheight 1000\nwidth 1000\nmap\n" + ("." * 1000 + "\n") * 1000)
    assert "memory budget of 100 MiB" in refusal(f, budget=MemoryBudget.of_mib(100))


def test_a_moving_ai_file_longer_than_its_header_says_is_not_read(tmp_path: Path) -> None:
    f = tmp_path / "long.map"
    with f.open("w") as out:
        out.write("type octile\nheight 2\nwidth 2\nmap\n..\n..\n")
        out.write("." * 1_000_000)
    assert "1,000,039 bytes, more than its header's 2 rows of 2 characters" in refusal(f)
    f.write_text("." * 1_000_000)  # no header at all
    assert "no 'map' line in its first 4096 bytes" in refusal(f)
    f.write_text("type octile\nheight 1234567890\nwidth 2\nmap\n..\n")
    assert "height '1234567890' is not a positive whole number" in refusal(f)


# ---- decoding in bands --------------------------------------------------------------------


def plain_grey(img: Image.Image) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]:
    """What the readers computed before decoding in bands: the whole image in floats."""
    if img.mode in ("RGBA", "LA", "PA") or (img.mode == "P" and "transparency" in img.info):
        rgba = np.asarray(img.convert("RGBA"))
        return rgba[..., :3].mean(axis=2).round().astype(np.uint8), rgba[..., 3] >= 128
    if img.mode in ("L", "1", "P", "RGB", "CMYK", "YCbCr"):
        grey = np.asarray(img.convert("RGB")).mean(axis=2).round().astype(np.uint8)
    else:
        values = np.asarray(img, dtype=np.float64)
        top = values.max() if values.max() > 0 else 1.0
        grey = (values * (255.0 / max(top, 255.0))).round().astype(np.uint8)
    return grey, np.ones(grey.shape, dtype=bool)


def _image(mode: str, rng: np.random.Generator) -> tuple[Image.Image, str]:
    shape = (37, 23)
    if mode == "P" or mode == "P+t":
        img = Image.fromarray(rng.integers(0, 256, shape, dtype=np.uint8), "L").convert("P")
        img.putpalette(rng.integers(0, 256, 3 * 256, dtype=np.uint8).tobytes())
        if mode == "P+t":
            img.info["transparency"] = bytes(rng.integers(0, 256, 256, dtype=np.uint8))
        return img, "png"
    if mode in ("I;16", "I", "F"):
        top = {"I;16": 65535, "I": 100_000, "F": 300}[mode]
        values = rng.integers(0, top, shape)
        dtype = {"I;16": np.uint16, "I": np.int32, "F": np.float32}[mode]
        img = Image.fromarray(values.astype(dtype), mode if mode != "I;16" else None)
        return img, "png" if mode == "I;16" else "tiff"
    bands = Image.getmodebands(mode)
    data = rng.integers(0, 256, (*shape, bands), dtype=np.uint8)
    base = {1: "L", 2: "LA", 3: "RGB", 4: "RGBA"}[bands]
    img = Image.fromarray(data if bands > 1 else data[..., 0], base)
    img = img.convert(mode) if mode != base else img
    return img, "jpeg" if mode == "CMYK" else "png" if mode != "1" else "bmp"


@pytest.mark.parametrize(
    "mode", ["1", "L", "P", "P+t", "RGB", "RGBA", "LA", "CMYK", "I;16", "I", "F"]
)
def test_grey_levels_read_in_bands_are_the_whole_images(
    tmp_path: Path, mode: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(raster, "BAND_PIXELS", 100)  # 4 rows a band: bands of 4 and 1 row
    img, fmt = _image(mode, np.random.default_rng(len(mode)))
    f = tmp_path / f"x.{fmt}"
    img.save(f, transparency=img.info["transparency"]) if mode == "P+t" else img.save(f)
    with Image.open(f) as saved:
        saved.load()
        want, want_opaque = plain_grey(saved)
    grey, opaque = read_image(f, MemoryBudget())
    assert (grey == want).all()
    assert (opaque if opaque is not None else np.ones_like(want_opaque)).tolist() == (
        want_opaque.tolist()
    )


@pytest.mark.parametrize("mode", ["trinary", "scale", "raw"])
@pytest.mark.parametrize("negate", [0, 1])
def test_ros_occupancy_of_every_grey_level_is_map_servers(
    tmp_path: Path, mode: str, negate: int
) -> None:
    img = np.arange(256, dtype=np.uint8).reshape(16, 16)
    Image.fromarray(img).save(tmp_path / "m.pgm")
    f = ros_yaml(tmp_path, "m.pgm", f"negate: {negate}\nmode: {mode}\n")
    level = img.astype(np.float64)
    if mode == "raw":
        known, p = level <= 100, level / 100.0
    else:
        known, p = np.ones(img.shape, bool), (level if negate else 255.0 - level) / 255.0
    got = read_map(f)
    assert (got.free == (known & (p < 0.196))).all()
    blocked = known & (p > 0.65)
    assert got.notes[0].endswith(
        f"({int(got.free.sum())} free, {int(blocked.sum())} occupied, "
        f"{256 - int(got.free.sum()) - int(blocked.sum())} unknown)"
    )


# ---- ROS YAML -----------------------------------------------------------------------------


def alias_bomb() -> str:
    """Nine aliases a level, nine levels: 387 million strings from 342 bytes."""
    text = 'a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n'
    for i in range(8):
        text += f"{chr(98 + i)}: &{chr(98 + i)} [" + ",".join([f"*{chr(97 + i)}"] * 9) + "]\n"
    return text


def test_yaml_anchors_and_aliases_are_refused_at_once(tmp_path: Path) -> None:
    Image.fromarray(framed(5, 5)).save(tmp_path / "m.pgm")
    f = tmp_path / "m.yaml"
    for text in (
        alias_bomb() + "image: m.pgm\nnegate: *i\n" + ROS_KEYS,
        "image: &name m.pgm\nnegate: 0\n" + ROS_KEYS,
        "image: m.pgm\nnegate: 0\n" + ROS_KEYS.replace("[0, 0, 0]", "&o [0, 0, 0]"),
    ):
        f.write_text(text)
        started = time.monotonic()
        message = refusal(f)
        assert time.monotonic() - started < 5
        assert "anchors and aliases (&name, *name) are not allowed" in message
        assert len(message) < 200


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("negate: " + "x" * 10_000, "negate must be 0 or 1, got 'xxxx"),
        ("negate: [" + ", ".join(["1"] * 5000) + "]", "negate must be 0 or 1, got [1, 1"),
        ("negate: 0\nmode: " + "y" * 10_000, "mode 'yyy"),
        ("negate: 0\nresolution: " + "9" * 400, "resolution must be a number, got 999"),
        ("negate: 0\nresolution: " + "9" * 5000, "a value cannot be read"),
        ("negate: " + "[" * 30_000 + "]" * 30_000, "nested too deeply"),
        ("negate: 0\n" + "k: v\n" * 20_000, "larger than 64 KiB"),
    ],
)
def test_values_in_errors_are_cut_short(tmp_path: Path, line: str, message: str) -> None:
    Image.fromarray(framed(5, 5)).save(tmp_path / "m.pgm")
    f = tmp_path / "m.yaml"
    body = ROS_KEYS.replace("resolution: 0.05\n", "") if "resolution:" in line else ROS_KEYS
    f.write_text(f"image: m.pgm\n{body}{line}\n")
    got = refusal(f)
    assert message in got
    assert len(got) < len(str(f)) + 180
    assert shorten("z" * 1000) == "'" + "z" * 76 + "..."


def test_an_image_outside_the_yaml_folder_gets_one_message_whether_it_exists_or_not(
    tmp_path: Path,
) -> None:
    folder = tmp_path / "maps"
    folder.mkdir()
    Image.fromarray(framed(5, 5)).save(tmp_path / "outside.png")
    (folder / "link.png").symlink_to(tmp_path / "outside.png")
    (folder / "dangling.png").symlink_to(tmp_path / "nothing.png")
    for there, absent in [
        ("../outside.png", "../nothing.png"),
        (str(tmp_path / "outside.png"), str(tmp_path / "nothing.png")),
        ("/etc/hostname", "/etc/no-such-file"),
        ("sub/../../outside.png", "sub/../../nothing.png"),
    ]:
        a = refusal(ros_yaml(folder, there))
        b = refusal(ros_yaml(folder, absent))
        assert a.replace(shorten(there), "X") == b.replace(shorten(absent), "X")
        assert "is not inside the YAML file's folder" in a and "not found" not in a
    # a link in the folder to a file outside it: the same, whether its target exists or not
    a, b = refusal(ros_yaml(folder, "link.png")), refusal(ros_yaml(folder, "dangling.png"))
    assert a.replace("link", "X") == b.replace("dangling", "X")
    assert "is not inside the YAML file's folder" in a
    # inside the folder, a missing image is named as missing; one there is read
    assert "image 'none.png' not found in" in refusal(ros_yaml(folder, "none.png"))
    (folder / "sub").mkdir()
    Image.fromarray(framed(5, 5)).save(folder / "sub" / "m.png")
    (folder / "inner.png").symlink_to(folder / "sub" / "m.png")
    for inside in ("sub/m.png", "inner.png", str(folder / "sub" / "m.png"), "./sub/../inner.png"):
        assert read_map(ros_yaml(folder, inside)).free.shape == (5, 5)


def test_the_yaml_folder_is_where_the_yaml_is_named_from(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    Image.fromarray(framed(5, 5)).save(tmp_path / "m.pgm")
    ros_yaml(tmp_path, "m.pgm")
    monkeypatch.chdir(tmp_path)
    assert read_map(Path("m.yaml")).free.shape == (5, 5)


# ---- through the CLI: one line, exit 2 ----------------------------------------------------


def test_image_files_that_are_not_images_are_one_line_errors(tmp_path: Path) -> None:
    cases = {
        "garbage.png": b"\x89PNG\r\n\x1a\n" + b"\x00" * 100,
        "truncated.png": b"",
        "script.png": b"%!PS-Adobe-3.0 EPSF-3.0\n%%BoundingBox: 0 0 10 10\n",
    }
    png = tmp_path / "noise.png"
    Image.fromarray(np.random.default_rng(0).integers(0, 256, (200, 200), np.uint8)).save(png)
    cases["truncated.png"] = png.read_bytes()[:20_000]
    for name, data in cases.items():
        f = tmp_path / name
        f.write_bytes(data)
        result = runner.invoke(cli, ["maze", "import", str(f)])
        assert result.exit_code == 2, (name, result.output)
        assert result.output.startswith("error: ") and result.output.count("\n") == 1, name
        assert "Traceback" not in result.output


def test_writing_the_map_where_it_cannot_be_written_is_one_line(tmp_path: Path) -> None:
    f = tmp_path / "plan.png"
    Image.fromarray(framed(20, 20)).save(f)
    result = runner.invoke(cli, ["maze", "import", str(f), "--out", str(tmp_path / "no" / "x")])
    assert result.exit_code == 2
    assert result.output.splitlines()[-1].startswith(f"error: cannot write {tmp_path}")
    assert "Traceback" not in result.output
