"""The layers of docs/ARCHITECTURE.md hold in the code, and what the text names exists.

Every ``import`` of every module under ``app/`` is read (at any depth, ``TYPE_CHECKING`` blocks
included), so a lazy import inside a function counts as much as one at the top.
"""

from __future__ import annotations

import ast
import importlib
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
APP = ROOT / "app"
#: the client, a distribution of its own (client/pyproject.toml): it imports nothing of app/
CLIENT = ROOT / "client" / "advisor_client"

#: what each part of app/ (and the client) may import of either (itself always); app.cli is
#: the composition root and may import anything
MAY_IMPORT: dict[str, set[str]] = {
    "advisor_client": set(),
    "app.arrays": set(),
    "app.kernels": set(),
    "app.domain": set(),
    "app.advice": {"app.domain"},
    "app.mapio": {"app.domain"},  # file formats (Pillow, PyYAML) read into the core's grids
    # the strategies' table: each entry's readable advisor, served form and compiled form
    "app.strategies": {"app.domain", "app.advice", "app.kernels"},
    "app.agents": {"app.domain", "app.advice", "app.kernels", "app.strategies"},
    # the experiments, and the maps of other formats they import (the IMDF venue)
    "app.experiments": {
        "app.domain",
        "app.advice",
        "app.kernels",
        "app.strategies",
        "app.agents",
        "app.mapio",
    },
    "app.service": {
        "app.domain",
        "app.advice",
        "app.kernels",
        "app.strategies",
        "advisor_client.protocol",
    },
    "app.viewer": {"app.domain", "app.advice"},
}
#: what every part of app/ may import: the array types (numpy's typing only)
EVERYWHERE = {"app.arrays"}
#: the core is numpy only; compiled code lives in two modules
NUMPY_ONLY = ("app.domain", "app.advice")
COMPILED = {"app.kernels", "app.service.wire.compiled"}


def module_name(path: Path) -> str:
    base = CLIENT.parent if path.is_relative_to(CLIENT) else ROOT
    parts = path.relative_to(base).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> set[str]:
    """Every module ``path`` imports (absolute names; relative imports resolved)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = (
        module_name(path) if path.name == "__init__.py" else module_name(path).rsplit(".", 1)[0]
    )
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(
                    package.split(".")[: len(package.split(".")) - node.level + 1]
                    + ([base] if base else [])
                )
            out.add(base)
            out |= {f"{base}.{alias.name}" for alias in node.names}
    return out


MODULES = {module_name(p): p for p in sorted([*APP.rglob("*.py"), *CLIENT.rglob("*.py")])}


def app_imports(name: str) -> set[str]:
    """The modules of app/ that ``name`` imports."""
    tops = ("app", "advisor_client")
    return {m for m in imports(MODULES[name]) if m in MODULES and m not in tops}


def parts_of(name: str) -> list[str]:
    """The parts of MAY_IMPORT that ``name`` belongs to (a module may be in nested parts)."""
    return [p for p in MAY_IMPORT if name == p or name.startswith(p + ".")]


def within(name: str, parts: set[str]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in parts)


@pytest.mark.parametrize("name", sorted(MODULES))
def test_module_imports_only_the_layers_below_it(name: str) -> None:
    parts = parts_of(name)
    if not parts:  # app.cli, app.__main__: the composition root
        assert name == "app" or name.startswith(("app.cli", "app.__main__")), f"{name}: no layer"
        return
    allowed = {q for p in parts for q in (p, *MAY_IMPORT[p])}
    if not name.startswith("advisor_client"):
        allowed |= EVERYWHERE
    wrong = sorted(m for m in app_imports(name) if not within(m, allowed))
    assert not wrong, f"{name} imports {wrong}"


@pytest.mark.parametrize("name", sorted(n for n in MODULES if n.startswith(NUMPY_ONLY)))
def test_the_core_imports_numpy_and_the_standard_library_only(name: str) -> None:
    third_party = {
        m.split(".")[0]
        for m in imports(MODULES[name])
        if m.split(".")[0] not in sys.stdlib_module_names
    }
    assert third_party <= {"numpy", "app", "__future__"}, f"{name} imports {sorted(third_party)}"


def test_numba_is_imported_by_the_two_compiled_modules_only() -> None:
    users = {
        name
        for name, path in MODULES.items()
        if any(m.split(".")[0] == "numba" for m in imports(path))
    }
    assert users == COMPILED


def test_no_module_imports_itself_through_others() -> None:
    graph = {name: app_imports(name) - {name} for name in MODULES}
    # a package's __init__ importing its submodules is not a circle through them
    state: dict[str, int] = {}

    def visit(name: str, trail: list[str]) -> None:
        state[name] = 1
        for other in sorted(graph[name]):
            if name.startswith(other + ".") or other.startswith(name + "."):
                continue
            if state.get(other) == 1:
                pytest.fail("import circle: " + " -> ".join([*trail, name, other]))
            if other not in state:
                visit(other, [*trail, name])
        state[name] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [])


# ---- what the text names ------------------------------------------------------------------------
PATH = re.compile(r"(?<![\w./-])((?:app|tests|docs|benchmarks|static|client)/[\w./-]*\w)")
DOTTED = re.compile(r":(?:mod|func|class|meth|data|attr):`~?((?:app|advisor_client)(?:\.\w+)+)`")
TEXTS = [
    *sorted(APP.rglob("*.py")),
    *sorted(CLIENT.rglob("*.py")),
    ROOT / "client" / "README.md",
    *sorted((ROOT / "tests").rglob("*.py")),
    *sorted((ROOT / "benchmarks").glob("*.py")),
    *sorted((ROOT / "docs").glob("*.md")),
    ROOT / "README.md",
    ROOT / "Makefile",
    ROOT / "Dockerfile",
]


def named_paths(text: str) -> set[str]:
    out = set()
    for m in PATH.finditer(text):
        path = m.group(1).split(":")[0].rstrip(".")
        pattern = text[m.end() : m.end() + 1] in ("{", "<", "*")  # a name made at run time
        if pattern or path.endswith("/"):
            continue
        out.add(path)
    return out


@pytest.mark.parametrize("source", TEXTS, ids=lambda p: str(p.relative_to(ROOT)))
def test_the_files_a_text_names_exist(source: Path) -> None:
    text = source.read_text(encoding="utf-8")
    missing = sorted(p for p in named_paths(text) if not (ROOT / p).exists() and not _generated(p))
    assert not missing, f"{source.relative_to(ROOT)} names files that do not exist: {missing}"


def _generated(path: str) -> bool:
    """Made by a run, not kept in the tree (results, test artifacts)."""
    return path.startswith(("results/", "test-artifacts/"))


@pytest.mark.parametrize("source", TEXTS, ids=lambda p: str(p.relative_to(ROOT)))
def test_the_modules_a_text_names_exist(source: Path) -> None:
    """A module named with a Sphinx role (mod, func, class, ...) is a module of app/, and the
    name after it something that module holds."""
    text = source.read_text(encoding="utf-8")
    missing = []
    for dotted in sorted(set(DOTTED.findall(text))):
        parts = dotted.split(".")
        cut = next((k for k in range(len(parts), 0, -1) if ".".join(parts[:k]) in MODULES), 0)
        target: object = importlib.import_module(".".join(parts[:cut])) if cut else None
        for attr in parts[cut:]:
            target = getattr(target, attr, None)
        if target is None:
            missing.append(dotted)
    assert not missing, f"{source.relative_to(ROOT)} names what does not exist: {missing}"
