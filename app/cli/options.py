"""How the command line shows and checks its options (shared by every command).

* On/off flags show no value type (typer would show ``<bool>`` beside ``--keep/--no-keep``).
* Options with a fixed set of values list them (``<random|left|...>``) and refuse another
  value saying which are allowed; :func:`choice` makes such an option. (Typer checks a
  ``Literal`` or an ``Enum`` itself, but words the refusal "Value error, ...".)
* A default too long for its column (a URL, a path, at 80 columns) is wrapped onto the next
  lines, not cut with "…": rich crops a table cell's words with an ellipsis unless the text
  says ``overflow="fold"``, and typer makes the ``[default: ...]`` text without it.

Both patch typer's internals: typer (0.29) has no setting for either (a flag's ``metavar=""``
would not reach its own ``--help``): docs/ARCHITECTURE.md, "Written here, or a library's".
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import typer
import typer.core
import typer.rich_utils
from rich.text import Text

_type_column = typer.core.TyperOption.display_type_rich


def _flag_type(self: typer.core.TyperOption, ctx: Any) -> str | None:
    return "" if self.is_flag else _type_column(self, ctx)


typer.core.TyperOption.display_type_rich = _flag_type  # type: ignore[method-assign]

_parameter_help = typer.rich_utils._get_parameter_help


def _folded_help(**kwargs: Any) -> Any:
    """An option's help, its default and the rest folded onto more lines, never cropped."""
    columns = _parameter_help(**kwargs)
    for item in columns.renderables:
        if isinstance(item, Text):
            item.overflow = "fold"
    return columns


typer.rich_utils._get_parameter_help = _folded_help


def check_choice(choices: Sequence[str]) -> Callable[[Any], Any]:
    """A callback refusing a value (or any value of a list) that is not one of ``choices``."""

    def check(value: Any) -> Any:
        for v in value if isinstance(value, list | tuple) else [value]:
            if v is not None and v not in choices:
                allowed = ", ".join(repr(c) for c in choices)
                raise typer.BadParameter(f"{v!r} is not one of {allowed}")
        return value

    return check


def choice(choices: Sequence[str], help: str, **options: Any) -> Any:
    """A ``typer.Option`` of type ``str`` taking one of ``choices`` (listed in --help)."""
    metavar = "<" + "|".join(choices) + ">"
    return typer.Option(help=help, metavar=metavar, callback=check_choice(choices), **options)
