"""Where an experiment's numbers go: ``results/<run>/`` with JSON, CSV, markdown and PNG files."""

from __future__ import annotations

import csv
import json
import math
import platform
import sys
from collections.abc import Mapping, Sequence
from dataclasses import asdict, is_dataclass
from datetime import UTC, datetime
from importlib.metadata import version
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only, no display

from matplotlib.figure import Figure

RESULTS_DIR = Path("results")


def default_run_dir(name: str) -> Path:
    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    return RESULTS_DIR / f"{name}-{stamp}"


def _plain(value: Any) -> Any:
    """JSON-safe: numpy scalars/arrays to Python, Paths to str, NaN/inf to None."""
    if is_dataclass(value) and not isinstance(value, type):
        return _plain(asdict(value))
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, str | bool) or value is None:
        return value
    if isinstance(value, Path):
        return str(value)
    if hasattr(value, "tolist"):
        return _plain(value.tolist())
    if isinstance(value, Sequence):
        return [_plain(v) for v in value]
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    return value


def header(experiment: str, args: Any, elapsed: float) -> dict[str, Any]:
    """What every result file opens with: the experiment, its settings (an ``Args``
    dataclass), the environment and the seconds it took."""
    return {
        "experiment": experiment,
        "settings": asdict(args),
        "environment": environment(),
        "elapsed_s": elapsed,
    }


def environment() -> dict[str, str]:
    """Versions that affect the numbers or the speed."""
    return {
        "python": platform.python_version(),
        "numpy": version("numpy"),
        "numba": version("numba"),
        "machine": platform.machine(),
        "command": " ".join(sys.argv),
    }


class RunDir:
    """One results directory; every write returns the path it wrote."""

    def __init__(self, path: Path):
        self.path = path
        path.mkdir(parents=True, exist_ok=True)
        self.written: list[Path] = []

    def _target(self, name: str) -> Path:
        p = self.path / name
        self.written.append(p)
        return p

    def json(self, name: str, data: Mapping[str, Any]) -> Path:
        p = self._target(f"{name}.json")
        p.write_text(json.dumps(_plain(data), indent=1) + "\n", encoding="utf-8")
        return p

    def csv(self, name: str, rows: Sequence[Mapping[str, Any]]) -> Path:
        p = self._target(f"{name}.csv")
        with p.open("w", newline="", encoding="utf-8") as fh:
            if rows:
                columns = list(dict.fromkeys(k for row in rows for k in row))  # union, in order
                writer = csv.DictWriter(fh, fieldnames=columns)
                writer.writeheader()
                for row in rows:
                    writer.writerow({k: _plain(v) for k, v in row.items()})
        return p

    def markdown(self, name: str, text: str) -> Path:
        p = self._target(f"{name}.md")
        p.write_text(text.rstrip() + "\n", encoding="utf-8")
        return p

    def figure(self, name: str, fig: Figure) -> Path:
        p = self._target(f"{name}.png")
        fig.savefig(p, dpi=120, bbox_inches="tight")
        return p


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A GitHub markdown table; the first column left-aligned, the rest right-aligned."""
    lines = ["| " + " | ".join(header) + " |"]
    lines.append("|" + "|".join([":---"] + ["---:"] * (len(header) - 1)) + "|")
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)
