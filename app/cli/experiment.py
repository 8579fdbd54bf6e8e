"""``python -m app experiment NAME``: run one experiment (or all) and write ``results/<run>/``.

Each experiment's options are its ``Args`` dataclass, declared once: a subcommand's options are
made from the fields (name, type, default) and their docstrings (help). ``all`` takes the
options of the experiments it runs; an option whose default differs between them shows each.
The experiment modules (numba, matplotlib) are imported only when their subcommand runs or
shows its help, so the rest of the command line does not pay for them.
"""

from __future__ import annotations

import ast
import functools
import importlib
import inspect
import itertools
import textwrap
import time
import typing
from dataclasses import MISSING, fields
from pathlib import Path
from types import ModuleType
from typing import Annotated, Any

import typer
from typer.core import TyperCommand, TyperGroup

from app.cli.maze import shown
from app.cli.options import choice
from app.domain.grid import MapError

#: name -> (module, one line of help); ``all`` runs ALL_PARTS in order
EXPERIMENTS = {
    "table1": ("table1", "Table I: mean reward with and without advice, per explorer."),
    "figure5": ("figure5", "Figure 5: P(M1|H) and reward over time, advised or not."),
    "figure6": ("figure6", "Figure 6: Q-learning reward per episode, advised or not."),
    "figure7": ("figure7", "Figure 7: advice per 100 steps as kappa varies."),
    "difficulty": ("difficulty", "How hard the maze is: random walkers' odds, dead ends."),
    "ablations": ("ablations", "One setting changed at a time: alpha0, experts, kappa, ..."),
    "strategies": ("strategies", "Every advising strategy on a suite of maps."),
    "buildings": ("buildings", "Lost explorers in buildings: paper, goal_aware and guide."),
    "visitors": ("visitors", "Visitors as they are (compliance, noise, sight) in buildings."),
    "all": ("paper", "The paper's protocol end to end: Table I, Figures 5-7, difficulty."),
}


def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of a dataclass (and of its bases), or the field's
    ``metadata["doc"]`` (the fields made from the strategies' entries)."""
    docs: dict[str, str] = {f.name: f.metadata["doc"] for f in fields(cls) if "doc" in f.metadata}
    for klass in reversed(cls.__mro__[:-1]):
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError):
            continue
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for item, after in itertools.pairwise(body):
            if not (isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name)):
                continue
            if isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant):
                docs[item.target.id] = " ".join(str(after.value.value).split())
    return docs


def _option_type(hint: Any) -> Any:
    """The command-line type of a field: a tuple of numbers is a repeatable option."""
    if typing.get_origin(hint) is tuple:
        return list[typing.get_args(hint)[0]]  # type: ignore[misc]
    return hint


def _panel(cls: type, name: str) -> str:
    """The help panel of field ``name``: the dataclass that declares it."""
    for klass in cls.__mro__:
        if name in inspect.get_annotations(klass):
            return PANELS.get(klass.__name__, f"{klass.__module__.rsplit('.', 1)[-1]} options")
    return "Options"


PANELS = {
    "CommonArgs": "Every experiment",
    "LearningArgs": "The Q-learner",
    "SuiteArgs": "The maps",
}


def _shown(default: Any) -> str | bool:
    """How a default is shown in the help: a path relative to the repository or to here."""
    if isinstance(default, Path):
        return shown(default)
    return default is not None


def options_of(classes: list[type]) -> list[inspect.Parameter]:
    """One keyword option per field of the dataclasses; a field whose default differs
    between them defaults to None (each experiment's own), and its help lists them."""
    seen: dict[str, tuple[Any, list[tuple[str, Any]], str, str]] = {}
    for cls in classes:
        hints, docs = typing.get_type_hints(cls), field_docs(cls)
        owner = cls.__module__.rsplit(".", 1)[-1]
        for f in fields(cls):
            default = f.default if f.default is not MISSING else None
            empty: tuple[Any, list[tuple[str, Any]], str, str] = (
                hints[f.name],
                [],
                docs.get(f.name, ""),
                _panel(cls, f.name),
            )
            hint, defaults, doc, panel = seen.get(f.name, empty)
            defaults.append((owner, default))
            seen[f.name] = (hint, defaults, doc, panel)
    out = []
    for name, (hint, defaults, doc, panel) in sorted(seen.items(), key=_panel_order):
        values = {repr(v) for _, v in defaults}
        if len(values) == 1:
            default = defaults[0][1]
            kind: Any = _option_type(hint)
            if isinstance(default, tuple):
                default = list(default)
        else:
            doc += " (default: " + "; ".join(f"{owner} {v}" for owner, v in defaults) + ")"
            default, kind = None, _option_type(hint) | None
        literal = typing.get_args(hint) if typing.get_origin(hint) is typing.Literal else None
        if literal:  # the values listed, another refused by name (choice)
            kind = str if len(values) == 1 else str | None
            option = choice(
                [str(v) for v in literal], doc, show_default=_shown(default),
                rich_help_panel=panel,
            )  # fmt: skip
        else:
            option = typer.Option(help=doc, show_default=_shown(default), rich_help_panel=panel)
        out.append(inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default,
                                     annotation=Annotated[kind, option]))  # fmt: skip
    return out


def _panel_order(item: tuple[str, tuple[Any, Any, str, str]]) -> int:
    """Every experiment's options first, the Q-learner's last (each panel in field order)."""
    panel = item[1][3]
    return 0 if panel == PANELS["CommonArgs"] else 2 if panel == PANELS["LearningArgs"] else 1


def help_text(doc: str) -> str:
    """A docstring as help: paragraphs joined into lines (indented lines kept as they are)."""
    paragraphs = textwrap.dedent(doc).strip().split("\n\n")
    joined = [p if p.startswith("    ") else " ".join(p.split()) for p in paragraphs]
    return "\n\n".join(joined)


def build(cls: type, options: dict[str, Any]) -> Any:
    """An experiment's ``Args`` from the options it has (unset ones: its defaults), checked."""
    names = {f.name for f in fields(cls)}
    given = {k: tuple(v) if isinstance(v, list) else v for k, v in options.items()}
    args = cls(**{k: v for k, v in given.items() if k in names and v is not None})
    args.check()
    return args


def _module(name: str) -> ModuleType:
    return importlib.import_module(f"app.experiments.{EXPERIMENTS[name][0]}")


def _report(name: str, out: Any, started: float) -> None:
    typer.echo(f"{name}: {time.perf_counter() - started:.1f}s, wrote {out.path}/")
    for p in out.written:
        if p.suffix == ".md":
            typer.echo(p.read_text(encoding="utf-8"))


@functools.cache
def command(name: str) -> TyperCommand:
    """The subcommand of experiment ``name``, its options made from its ``Args``."""
    module = _module(name)
    classes = [part.Args for part in module.PARTS] if name == "all" else [module.Args]

    def run(out: Path | None = None, **options: Any) -> None:
        from app.experiments.output import RunDir, default_run_dir

        run_dir = RunDir(out or default_run_dir(name))
        started = time.perf_counter()
        try:
            args = [build(cls, options) for cls in classes]
            result = module.run(*args, run_dir)
        except (ValueError, MapError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=2) from None
        if name == "all":
            typer.echo(" ".join(f"{k} {v:.1f}s" for k, v in result.items()))
        _report(name, run_dir, started)

    out_help = "Results directory (default: results/<name>-<time>)."
    params = [
        *options_of(classes),
        inspect.Parameter("out", inspect.Parameter.KEYWORD_ONLY, default=None,
                          annotation=Annotated[Path | None, typer.Option(help=out_help)]),
    ]  # fmt: skip
    run.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    run.__annotations__ = {p.name: p.annotation for p in params}
    run.__doc__ = help_text(module.__doc__ or EXPERIMENTS[name][1])
    app = typer.Typer(add_completion=False, pretty_exceptions_enable=False, rich_markup_mode=None)
    app.command(name, short_help=EXPERIMENTS[name][1])(run)
    made = typer.main.get_command(app)
    assert isinstance(made, TyperCommand)
    return made


class ExperimentGroup(TyperGroup):
    """The experiments as subcommands, each built (its module imported) only when used."""

    def list_commands(self, ctx: Any) -> list[str]:
        return list(EXPERIMENTS)

    def get_command(self, ctx: Any, cmd_name: str) -> TyperCommand | None:
        return command(cmd_name) if cmd_name in EXPERIMENTS else None


experiment_cli = typer.Typer(
    cls=ExperimentGroup,
    help="Reproduce the paper's Table I and Figures 5-7 (or the ablations, or compare the "
    "advising strategies) on a maze; `experiment NAME --help` lists NAME's options.",
    no_args_is_help=True,
    add_completion=False,
)
