"""Shared helpers for benchmarks: machine description and rewriting a marked docs section."""

from __future__ import annotations

import argparse
import os
import platform
import re
import statistics
import sys
import time
from collections.abc import Callable
from importlib import metadata
from pathlib import Path


def arguments(doc: str | None) -> argparse.ArgumentParser:
    """A benchmark's parser: its ``--help`` shows the first paragraph of the script's
    docstring ``doc`` with its lines as written."""
    return argparse.ArgumentParser(
        description=(doc or "").split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )


def machine() -> str:
    pkgs = ", ".join(
        f"{name} {metadata.version(name)}"
        for name in ("numpy", "numba", "fastapi", "uvicorn", "pydantic", "sqlalchemy")
        if _installed(name)
    )
    return (
        f"{os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}, "
        f"{pkgs}; {time.strftime('%Y-%m-%d')}"
    )


def _installed(name: str) -> bool:
    try:
        metadata.version(name)
    except metadata.PackageNotFoundError:
        return False
    return True


def median_of(fn: Callable[[], float], repeats: int) -> tuple[float, list[float]]:
    """Run ``fn`` (which returns one measurement) ``repeats`` times; median and all values."""
    values = [fn() for _ in range(repeats)]
    return statistics.median(values), values


def write_section(doc: Path, key: str, body: str) -> None:
    """Replace the text between ``<!-- key:start -->`` and ``<!-- key:end -->`` in ``doc``
    (appending the marked block if absent)."""
    start, end = f"<!-- {key}:start -->", f"<!-- {key}:end -->"
    block = f"{start}\n{body.rstrip()}\n{end}"
    text = doc.read_text(encoding="utf-8") if doc.exists() else "# Performance\n"
    pattern = re.compile(re.escape(start) + ".*?" + re.escape(end), re.S)
    text = (
        pattern.sub(lambda _: block, text) if pattern.search(text) else text + "\n" + block + "\n"
    )
    doc.write_text(text, encoding="utf-8")


def command_line() -> str:
    return "python " + " ".join(sys.argv)
