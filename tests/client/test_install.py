"""The client installs and imports alone, in a fresh virtual environment: no server code, none
of the server's dependencies, and no ``app`` package to clash with a user's own."""

from __future__ import annotations

import importlib.metadata as md
import json
import os
import shutil
import subprocess
import sys
import venv
from pathlib import Path

import pytest
from packaging.requirements import Requirement

REPO = Path(__file__).resolve().parents[2]
#: what the client may need at run time (its dependencies and theirs)
ALLOWED = {"httpx", "websockets", "numpy", "tenacity"}


def closure(names: set[str]) -> set[str]:
    """These distributions and everything they require (no extras), as installed here."""
    seen: set[str] = set()
    todo = [md.distribution(n).metadata["Name"] for n in names]
    while todo:
        name = todo.pop()
        key = name.lower().replace("_", "-")
        if key in seen:
            continue
        seen.add(key)
        for text in md.requires(name) or []:
            req = Requirement(text)
            if req.marker is None or req.marker.evaluate({"extra": ""}):
                todo.append(req.name)
    return seen


def top_levels(dist_name: str) -> set[str]:
    files = md.distribution(dist_name).files or []
    tops = {f.parts[0] for f in files if len(f.parts) > 1 or f.suffix == ".py"}
    return {t for t in tops if not t.endswith((".dist-info", ".data")) and t != ".."}


@pytest.mark.slow
def test_the_client_installs_and_imports_without_the_server(tmp_path: Path) -> None:
    source = tmp_path / "client"
    shutil.copytree(REPO / "client", source, ignore=shutil.ignore_patterns("build", "*.egg-info"))
    wheels = tmp_path / "wheels"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
         "--no-index", str(source), "-w", str(wheels)],
        check=True, capture_output=True,
    )  # fmt: skip
    (wheel,) = wheels.glob("hidden_goal_advisor_client-*.whl")
    fresh = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(fresh)
    python = fresh / "bin" / "python"
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-index",
         "--no-deps", str(wheel)],
        check=True, capture_output=True,
    )  # fmt: skip
    # its dependencies, taken from this environment: only those (symlinked into one folder)
    deps = tmp_path / "deps"
    deps.mkdir()
    needed = closure(ALLOWED)
    for dist in needed:
        for top in top_levels(dist):
            target = Path(str(md.distribution(dist).locate_file(top)))
            if target.exists():
                (deps / top).symlink_to(target)
        info = md.distribution(dist)._path  # type: ignore[attr-defined]
        (deps / info.name).symlink_to(info)
    site = next((fresh / "lib").glob("python3*/site-packages"))
    (site / "deps.pth").write_text(f"{deps}\n")
    user = tmp_path / "user"  # a user's own package named app
    (user / "app").mkdir(parents=True)
    (user / "app" / "__init__.py").write_text("MINE = True\n")
    probe = """
import importlib.metadata as md, json, sys
import advisor_client
from advisor_client import AdvisorClient, AdvisorError, DecisionFrame
from advisor_client.protocol import pack, unpack
import app
heavy = [m for m in ("numba", "fastapi", "viser", "sqlalchemy", "psycopg", "uvicorn")
         if m in sys.modules]
missing = []
for m in ("numba", "fastapi", "viser", "sqlalchemy"):
    try:
        __import__(m)
    except ImportError:
        missing.append(m)
print(json.dumps({"requires": md.requires("hidden-goal-advisor-client"), "heavy": heavy,
                  "missing": missing, "app_is_mine": getattr(app, "MINE", False),
                  "client": advisor_client.__file__}))
"""
    env = {"PATH": os.environ.get("PATH", ""), "PYTHONPATH": str(user), "PYTHONNOUSERSITE": "1"}
    out = subprocess.run(
        [str(python), "-c", probe], check=True, capture_output=True, text=True, cwd=tmp_path,
        env=env,
    )  # fmt: skip
    got = json.loads(out.stdout)
    assert got["heavy"] == [] and got["missing"] == ["numba", "fastapi", "viser", "sqlalchemy"]
    assert got["app_is_mine"] is True
    assert got["client"].startswith(str(site))
    runtime = {Requirement(r).name for r in got["requires"] if "extra" not in r}
    assert runtime == ALLOWED
