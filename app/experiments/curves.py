"""The experiments' strategies: their options made from the strategies' entries
(:mod:`app.strategies`), and the configurations run (a strategy at a cost level).

An experiment comparing strategies takes, besides its own arguments, the fields of
:func:`strategy_args`: which strategies to run (each a curve), per strategy with a cost level
its levels (``--<name>-levels``, the entry's values unless the experiment gives its own), and
every parameter the strategies read (``--beta``, ``--p-lost``, ...; the random rule's seed is
the experiment's). A strategy registered after the options were made runs at its entry's levels.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, make_dataclass
from typing import Any, Generic, TypeVar

import numpy as np

from app import strategies
from app.advice.advisor import DEFAULT_STRATEGY
from app.advice.params import StrategyParams
from app.arrays import FloatArray

#: the 97.5% point of the standard normal: two-sided 95% intervals
Z95 = 1.959963984540054
#: parameters an experiment sets itself (the random rule draws from the experiment's streams)
OWN = frozenset({"seed"})


def strategy_args(
    name: str, curves: tuple[str, ...], levels: Mapping[str, tuple[float, ...]] | None = None
) -> type:
    """A dataclass of the options of an experiment comparing ``curves`` (its default
    strategies; ``levels``: the experiment's own default levels of some). Each field's help is
    its ``metadata["doc"]``."""
    levels = levels or {}
    specs: list[tuple[str, Any, Any]] = [(
        "strategies", tuple[str, ...],
        field(default=curves, metadata={"doc": "Strategies compared, a curve each (GET "
              "/strategies lists them; one without a compiled form runs the readable loop)."}),
    )]  # fmt: skip
    read: list[str] = []
    for n in curves:
        entry = strategies.get(n)
        read += [p for p in entry.reads if p not in read and p not in OWN]
        if entry.level is not None:
            values = tuple(levels.get(n, entry.level.values))
            doc = (f"{n}: its {entry.level.param} levels (the default --kappa, or the "
                   f"parameter's default, is always among them).")  # fmt: skip
            specs.append(
                (f"{n}_levels", tuple[float, ...], field(default=values, metadata={"doc": doc}))
            )
    meta = {f.name: f for f in fields(StrategyParams)}
    for p in read:
        f = meta[p]
        kind = int if f.type == "int" else float
        specs.append((p, kind, field(default=f.default, metadata={"doc": f.metadata["doc"]})))
    return make_dataclass(name, specs)


def levels_of(args: Any, name: str) -> tuple[float, ...]:
    """The levels of strategy ``name`` asked of the experiment (its entry's when it has no
    option of its own)."""
    entry = strategies.get(name)
    if entry.level is None:
        return ()
    own = getattr(args, f"{name}_levels", None)
    return tuple(entry.level.values if own is None else own)


def base_params(args: Any) -> StrategyParams:
    """The strategies' parameters as the experiment's options set them."""
    given = {f.name: getattr(args, f.name) for f in fields(StrategyParams) if hasattr(args, f.name)
             and f.name not in OWN}  # fmt: skip
    return StrategyParams(**given)


def check_strategies(args: Any) -> None:
    """ValueError for an unknown strategy, a bad level or a parameter out of bounds."""
    for name in args.strategies:
        strategies.get(name)  # ValueError naming the known ones
        for v in levels_of(args, name):
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name}: levels must be finite numbers >= 0, got {v}")
    base_params(args).check()


@dataclass(frozen=True)
class Config:
    """One point of one curve: a strategy at one cost level (``none``: no advice)."""

    curve: str  # a strategy's name, "none", or a variant "<strategy> <param>=<value>"
    strategy: str  # the strategy run (the default one for ``none``, which gives no advice)
    level: float  # the curve's cost level (nan: none, or a strategy without a level)
    kappa: float
    params: StrategyParams = field(default_factory=StrategyParams)
    default: bool = False  # the curve's default level

    @property
    def key(self) -> str:
        return self.curve if math.isnan(self.level) else f"{self.curve}@{self.level:g}"

    @property
    def advised(self) -> bool:
        return self.curve != "none"


Spec = TypeVar("Spec")


@dataclass
class SuiteRuns(Generic[Spec]):
    """What the runs of a suite of maps share: its maps and the configurations run on each (an
    experiment's results add its measures, one row per map, one column per task)."""

    maps: list[Spec]
    configs: list[Config]


def configs(args: Any, variants: tuple[str, ...] = ()) -> list[Config]:
    """Every configuration an experiment runs: no advice, then each strategy's levels
    ascending (its default level among them), then ``variants`` ("<strategy> <param>=<value>",
    at the default kappa; one that sets the value the options set is the strategy's own)."""
    base, k0 = base_params(args), float(args.kappa)
    out = [Config("none", DEFAULT_STRATEGY, math.nan, k0, base, True)]
    for name in args.strategies:
        entry = strategies.get(name)
        if entry.level is None:
            out.append(Config(name, name, math.nan, k0, base, True))
            continue
        param = entry.level.param
        default = k0 if param == "kappa" else float(getattr(base, param))
        for v in sorted({*map(float, levels_of(args, name)), default}):
            s = entry.at_level(entry.settings(k0, args.window, base), v)
            out.append(Config(name, name, v, s.kappa, s.params, v == default))
    for text in variants:
        name, _, assignment = text.partition(" ")
        param, _, value = assignment.partition("=")
        entry = strategies.get(name)
        if param not in entry.reads:
            raise ValueError(f"variant {text!r}: {name} does not read {param!r}")
        whole = isinstance(getattr(base, param), int)
        typed = int(value) if whole else float(value)
        if typed == getattr(base, param):
            continue  # the strategy's own curve has it
        given = {**entry.in_force(base), param: typed}
        params = entry.settings(k0, args.window, given)
        out.append(Config(f"{name} {param}={float(value):g}", name, k0, k0, params.params))
    return out


def paired(a: FloatArray, b: FloatArray) -> tuple[float, float, float]:
    """Mean of a - b over paired tasks (success 0/1), with a 95% normal interval clipped to
    the possible range [-1, 1]."""
    d = (np.asarray(a, dtype=np.float64) - b).ravel()
    mean = float(d.mean())
    se = float(d.std(ddof=1)) / math.sqrt(d.size) if d.size > 1 else math.inf
    return mean, max(-1.0, mean - Z95 * se), min(1.0, mean + Z95 * se)
