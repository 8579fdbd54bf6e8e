"""The client installs and imports alone, in a fresh virtual environment: no server code, none
of the server's dependencies, and no ``app`` package to clash with a user's own. The service's
``pip install .`` needs no index either: its distribution holds the client too.

Both build a wheel from a copy of the sources and install it into a fresh virtual environment
offline (``--no-index``), its dependencies taken from this environment (symlinked into one
folder on its path), so pip resolves every requirement against what is installed or fails."""

from __future__ import annotations

import importlib.metadata as md
import json
import os
import shutil
import subprocess
import sys
import tomllib
import venv
from pathlib import Path

import pytest
from packaging.requirements import Requirement

REPO = Path(__file__).resolve().parents[2]
#: what the client may need at run time (its dependencies and theirs)
ALLOWED = {"httpx", "websockets", "numpy", "tenacity"}


def closure(requirements: set[str]) -> set[str]:
    """The distributions these requirements name and everything they require (with the
    extras asked for, as ``uvicorn[standard]``), as installed here."""
    seen: set[tuple[str, str]] = set()
    names: set[str] = set()
    todo = [Requirement(r) for r in requirements]
    while todo:
        req = todo.pop()
        if req.marker is not None and not req.marker.evaluate({"extra": ""}):
            continue
        name = md.distribution(req.name).metadata["Name"]
        names.add(name.lower().replace("_", "-"))
        for extra in {"", *req.extras}:
            if (name, extra) in seen:
                continue
            seen.add((name, extra))
            for text in md.requires(name) or []:
                needed = Requirement(text)
                if needed.marker is None or needed.marker.evaluate({"extra": extra}):
                    needed.marker = None
                    todo.append(needed)
    return names


def top_levels(dist_name: str) -> set[str]:
    files = md.distribution(dist_name).files or []
    tops = {f.parts[0] for f in files if len(f.parts) > 1 or f.suffix == ".py"}
    return {t for t in tops if not t.endswith((".dist-info", ".data")) and t != ".."}


def fresh_venv(tmp_path: Path, requirements: set[str]) -> tuple[Path, Path]:
    """A new virtual environment (no pip of its own) that sees only the distributions of
    ``requirements`` and their closure, symlinked from this one into a folder on its path:
    its python and its site-packages."""
    fresh = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(fresh)
    deps = tmp_path / "deps"
    deps.mkdir()
    for dist in closure(requirements):
        for top in top_levels(dist):
            target = Path(str(md.distribution(dist).locate_file(top)))
            if target.exists() and not (deps / top).exists():
                (deps / top).symlink_to(target)
        info = md.distribution(dist)._path  # type: ignore[attr-defined]
        (deps / info.name).symlink_to(info)
    site = next((fresh / "lib").glob("python3*/site-packages"))
    (site / "deps.pth").write_text(f"{deps}\n")
    return fresh / "bin" / "python", site


def pip(*args: str) -> None:
    """This environment's pip; AssertionError with its output if it fails."""
    run = subprocess.run([sys.executable, "-m", "pip", *args], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr


def copy_sources(tmp_path: Path, *parts: str) -> Path:
    source = tmp_path / "source"
    ignore = shutil.ignore_patterns("build", "*.egg-info", "__pycache__")
    for part in parts:
        if (REPO / part).is_dir():
            shutil.copytree(REPO / part, source / part, ignore=ignore)
        else:
            source.mkdir(exist_ok=True)
            shutil.copy2(REPO / part, source / part)
    return source


@pytest.mark.slow
def test_the_client_installs_and_imports_without_the_server(tmp_path: Path) -> None:
    source = copy_sources(tmp_path, "client") / "client"
    wheels = tmp_path / "wheels"
    pip("wheel", "-q", "--no-deps", "--no-build-isolation", "--no-index", str(source),
        "-w", str(wheels))  # fmt: skip
    (wheel,) = wheels.glob("hidden_goal_advisor_client-*.whl")
    python, site = fresh_venv(tmp_path, ALLOWED)
    pip("--python", str(python), "install", "-q", "--no-index", "--no-deps", str(wheel))
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


@pytest.mark.slow
def test_pip_install_dot_needs_no_index_and_gives_the_service_and_the_client(
    tmp_path: Path,
) -> None:
    """``pip install .`` from a clone: every requirement of the service resolved offline
    (``--no-index``: nothing from an index, where the client's name is not registered), the
    client coming with the service's distribution. About 15 s: the build and the imports."""
    source = copy_sources(tmp_path, "pyproject.toml", "README.md", "LICENSE", "app", "client")
    project = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    build = {"setuptools", "wheel"}  # --no-build-isolation: the backend from the environment
    python, site = fresh_venv(tmp_path, set(project["dependencies"]) | build)
    # not --no-deps: pip checks each requirement against what the environment has
    pip("--python", str(python), "install", "-q", "--no-index", "--no-build-isolation",
        str(source))  # fmt: skip
    probe = """
import importlib.metadata as md, json
import app, advisor_client
from advisor_client import AdvisorClient
from app.cli import cli
from app.service.config import Settings
files = {str(f) for f in md.distribution("hidden-goal-advisor").files or []}
print(json.dumps({"app": app.__file__, "client": advisor_client.__file__,
                  "requires": md.requires("hidden-goal-advisor"),
                  "typed": "advisor_client/py.typed" in files,
                  "licence": md.metadata("hidden-goal-advisor")["License-Expression"],
                  "map": "app/domain/maps/default.txt" in files}))
"""
    env = {"PATH": os.environ.get("PATH", ""), "PYTHONNOUSERSITE": "1"}
    out = subprocess.run(
        [str(python), "-c", probe], capture_output=True, text=True, cwd=tmp_path, env=env
    )
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert got["app"].startswith(str(site)) and got["client"].startswith(str(site))
    assert got["typed"] and got["map"] and got["licence"] == "MIT"
    names = {Requirement(r).name for r in got["requires"]}
    assert "hidden-goal-advisor-client" not in names and names >= ALLOWED
    version = subprocess.run(
        [str(python), "-m", "app", "--version"], capture_output=True, text=True, cwd=tmp_path,
        env=env,
    )  # fmt: skip
    assert version.stdout.strip() == f"advisor {project['version']}", version.stderr
