"""What ``maze import`` takes against the memory budget's estimate (app/mapio/budget.py).

    .venv/bin/python -m tests.reliability.map_import_figures            # every case (~2 min)
    .venv/bin/python -m tests.reliability.map_import_figures plan:500:500:L:1 movingai:2000:50

Each case is imported in a process of its own (``python -m app maze import``, default
settings, 8 goals, the budget set out of the way); its peak RSS over a tiny import's is compared
with :meth:`MemoryBudget.image_estimate` / :meth:`MemoryBudget.text_estimate`. A case is
``plan:ROWS:COLS:MODE:MERGE`` (a floor plan all floor inside a black outline, in a Pillow mode),
``ros:ROWS:COLS:MODE:MERGE`` (the same as a ROS map) or ``movingai:ROWS:COLS``. Not run by
pytest.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

from app.mapio.budget import MIB, MemoryBudget
from tests.reliability.test_map_import import peak_bytes

CASES = [
    "plan:1000:1000:L:1",
    "plan:4000:4000:L:40",
    "plan:4000:4000:1:40",
    "plan:4000:4000:P:40",
    "plan:4000:4000:RGB:40",
    "plan:4000:4000:RGBA:40",
    "plan:4000:4000:I;16:40",
    "plan:4000:4000:I:40",
    "plan:4000:4000:F:40",
    "plan:700:700:RGBA:1",
    "plan:20000:20:L:1",
    "plan:8000:8000:1:100",
    "ros:4000:4000:L:40",
    "ros:1000:1000:L:1",
    "movingai:1000:1000",
    "movingai:4000:100",
    "movingai:50000:8",
]
SUFFIX = {"I": "tif", "F": "tif"}


def plan(rows: int, cols: int, mode: str, folder: Path, level: int = 255) -> tuple[Path, bool]:
    a = np.full((rows, cols), level, np.uint8)
    a[0, :] = a[-1, :] = a[:, 0] = a[:, -1] = 0
    img = Image.fromarray(a)
    if mode in ("RGBA", "LA", "PA"):
        img = Image.merge("RGBA", (img, img, img, Image.new("L", img.size, 255)))
    img = img.convert(mode)
    f = folder / f"plan-{mode.replace(';', '')}.{SUFFIX.get(mode, 'png')}"
    img.save(f)
    return f, mode in ("RGBA", "LA", "PA")


def case(spec: str, folder: Path, budget: MemoryBudget) -> tuple[list[str], int]:
    kind, *dims = spec.split(":")
    rows, cols = int(dims[0]), int(dims[1])
    if kind == "movingai":
        f = folder / "map.map"
        inner = "@" + "." * (cols - 2) + "@\n"
        f.write_text(
            f"type octile\nheight {rows}\nwidth {cols}\nmap\n"
            + "@" * cols
            + "\n"
            + inner * (rows - 2)
            + "@" * cols
            + "\n"
        )
        return [str(f)], budget.text_estimate(cols, rows)
    mode, merge = dims[2], int(dims[3])
    image, alpha = plan(rows, cols, mode, folder, 254 if kind == "ros" else 255)
    estimate = budget.image_estimate(cols, rows, mode, merge, alpha)
    if kind == "plan":
        return [str(image), "--merge", str(merge)], estimate
    f = folder / "map.yaml"
    f.write_text(
        f"image: {image.name}\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 0.65\n"
        "free_thresh: 0.196\nnegate: 0\n"
    )
    return [str(f), "--merge", str(merge)], estimate


def main(specs: list[str]) -> None:
    budget = MemoryBudget()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        out = str(folder / "out.txt")
        tiny, _ = plan(30, 40, "L", folder)
        base = peak_bytes(str(tiny), "--out", out)
        print(f"a tiny import's peak RSS: {base / MIB:.1f} MiB")
        for spec in specs:
            args, estimate = case(spec, folder, budget)
            started = time.monotonic()
            took = peak_bytes(*args, "--out", out, "--max-memory", "1000000") - base
            print(
                f"{spec:24s} took {took / MIB:7.1f} MiB  estimate {estimate / MIB:7.1f} MiB  "
                f"{took / estimate:5.0%}  {time.monotonic() - started:5.1f} s"
            )


if __name__ == "__main__":
    main(sys.argv[1:] or CASES)
