"""Advising strategies compared: success against advice given, and who advice helps or hurts.

Beyond the paper (issue 8). For every fixed-policy explorer x strategy x cost level,
``--tasks`` random one-shot tasks per map (goal drawn uniformly from the map's goals, start at
'S', at most ``--steps`` moves) on the ``--maze`` map and on ``--maps`` generated mazes (the
first half perfect, the rest braided with ``--braid``; ``--map-size`` square, 8 goals).
An advised explorer samples its move from the advice: theta_s, or theta^w_s for goal-aware
advice. Q-learning is left out: its compiled kernel knows only the paper's rule.

Cost levels (each strategy's entry says which: kappa for ``paper`` and ``goal_aware``,
``n_steps`` for ``early``, the threshold for ``importance`` and ``mistake``, the rate for
``random``; ``always`` has one level), ``--<strategy>-levels`` to change them. The default
level of each curve is ``--kappa`` (0.5) and the parameters' defaults (``--beta`` for
``goal_aware``, 0: ruling goals out only); ``--variants`` adds curves at the default kappa
only (other betas). The targets are about ``--candidate`` (goal_aware) against
``--baseline`` (paper).

Randomness: per map its own streams for the generated maze, the expert data and the tasks'
goals; per task one explorer stream ``rng_for(seed, "strategies", map, explorer, task)``
shared by every strategy and level, so the differences between strategies (and with no
advice) are paired; the ``random`` rule draws from a stream of its own.

    python -m app experiment strategies [--tasks 50] [--maps 10] [--workers 2]

The report: rates with intervals, paired changes, targets, plots.

Success rates get 95% Wilson intervals. A change between two configurations (a strategy
against no advice, goal-aware against the paper's rule) is paired task by task (the same goal
and the same explorer stream): the mean of the per-task differences with a 95% normal
interval. Advice per 100 steps is the mean over tasks of 100 x advice / moves, as in Table I.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import asdict
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from app import strategies
from app.agents.explorers import FIXED_EXPLORERS
from app.arrays import FloatArray
from app.experiments.common import timed, wilson
from app.experiments.curves import Config, base_params, paired
from app.experiments.output import RunDir, header, markdown_table
from app.experiments.strategy_suite import (
    Args,
    Results,
    map_info,
    prepare_world,
    run_all,
)

SCOPES = ("suite", "file", "perfect", "braided")
#: The target explorers of the issue's first target.
RANDOM_WALKERS = ("random", "random-avoid")
#: An explorer is competent if it succeeds in at least this share of tasks without advice.
COMPETENT = 0.5


def scope_maps(results: Results, scope: str) -> list[int]:
    if scope == "suite":
        return [s.index for s in results.maps]
    return [s.index for s in results.maps if s.kind == scope]


def level_name(c: Config) -> str:
    """The parameter a configuration's curve sweeps ("" for none, or no level)."""
    level = strategies.get(c.strategy).level
    return "" if not c.advised or level is None else level.param


def advice_per_100(m: dict[str, FloatArray]) -> FloatArray:
    out: FloatArray = 100.0 * m["advice"] / np.maximum(m["steps"], 1)
    return out


def row(
    results: Results, explorer: str, c: Config, maps: list[int], none: dict[str, FloatArray]
) -> dict[str, Any]:
    """Everything measured for one explorer and configuration over ``maps``."""
    m = {k: v[maps] for k, v in results.data[explorer][c.key].items()}
    n0 = {k: v[maps] for k, v in none.items()}
    n, k = int(m["success"].size), int(m["success"].sum())
    lo, hi = wilson(k, n)
    failures = n - k
    diff = paired(m["success"], n0["success"])
    per_map = m["success"].mean(axis=1) - n0["success"].mean(axis=1)
    return {
        "explorer": explorer,
        "curve": c.curve,
        "key": c.key,
        "level_name": level_name(c),
        "level": c.level,
        "default": c.default,
        "kappa": c.kappa,
        "params": strategies.get(c.strategy).in_force(c.params) if c.advised else {},
        "maps": len(maps),
        "tasks": n,
        "successes": k,
        "success": k / n,
        "success_ci_low": lo,
        "success_ci_high": hi,
        "advice_per_100_steps": float(advice_per_100(m).mean()),
        "advice_per_task": float(m["advice"].mean()),
        "mean_steps": float(m["steps"].mean()),
        "failures": failures,
        "trapped": int(m["trapped"].sum()),
        "trapped_share_of_failures": float(m["trapped"].sum() / failures) if failures else 0.0,
        "other_dead_end_share": float(m["other_dead_end_share"].mean()),
        "goals_ruled_out": float(m["ruled_out"].mean()),
        "change_vs_none": diff[0],
        "change_vs_none_ci_low": diff[1],
        "change_vs_none_ci_high": diff[2],
        "maps_better": int((per_map > 0).sum()),
        "maps_worse": int((per_map < 0).sum()),
    }


def summarise(results: Results, args: Args) -> dict[str, Any]:
    """Rows per scope and per map, the helps/hurts table and the targets."""
    rows, map_rows = [], []
    for explorer in FIXED_EXPLORERS:
        none = results.data[explorer]["none"]
        for c in results.configs:
            for scope in SCOPES:
                maps = scope_maps(results, scope)
                if maps:
                    rows.append({"scope": scope, **row(results, explorer, c, maps, none)})
            for spec in results.maps:
                r = row(results, explorer, c, [spec.index], none)
                map_rows.append({"map": spec.index, "map_name": spec.name, "kind": spec.kind, **r})
    return {
        "rows": rows,
        "map_rows": map_rows,
        "versus": versus(results, args),
        "targets": targets(results, rows, args),
    }


def versus(results: Results, args: Args) -> list[dict[str, Any]]:
    """The candidate at its default level against every other curve's default, paired per
    task over the suite (positive: the candidate succeeds more often)."""
    d = defaults(results, args)
    cand = d[args.candidate]
    out = []
    for explorer in FIXED_EXPLORERS:
        data = results.data[explorer]
        for name, c in d.items():
            if name == args.candidate:
                continue
            diff = paired(data[cand.key]["success"], data[c.key]["success"])
            out.append(
                {
                    "explorer": explorer,
                    "candidate": cand.key,
                    "other": c.key,
                    "difference": diff[0],
                    "difference_ci_low": diff[1],
                    "difference_ci_high": diff[2],
                }
            )
    return out


def find(rows: list[dict[str, Any]], scope: str, explorer: str, key: str) -> dict[str, Any]:
    for r in rows:
        if r["scope"] == scope and r["explorer"] == explorer and r["key"] == key:
            return r
    raise KeyError((scope, explorer, key))


def defaults(results: Results, args: Args) -> dict[str, Config]:
    """The default configuration of no advice and of each strategy compared."""
    curves = ("none", *args.strategies)
    return {c.curve: c for c in results.configs if c.default and c.curve in curves}


def targets(results: Results, rows: list[dict[str, Any]], args: Args) -> dict[str, Any]:
    """The targets, measured on the whole suite.

    1. the candidate (``--candidate``) at the default kappa succeeds more often than the
       baseline (``--baseline``) at the same kappa (paired interval above 0) with no more
       advice (per 100 steps and per task), for the random walkers; also: at how many of the
       baseline's levels some candidate level gives more success with no more advice per
       100 steps.
    2. the recommended default (the candidate at the default kappa) does not lower the
       success of a competent explorer (no-advice success >= COMPETENT) below its no-advice
       level.
    """
    d = defaults(results, args)
    ga, pa = d[args.candidate], d[args.baseline]
    first = []
    for explorer in RANDOM_WALKERS:
        g, p = find(rows, "suite", explorer, ga.key), find(rows, "suite", explorer, pa.key)
        data = results.data[explorer]
        diff = paired(data[ga.key]["success"], data[pa.key]["success"])
        curve = [c for c in results.configs if c.curve == args.candidate]
        paper_levels = [c for c in results.configs if c.curve == args.baseline]
        dominated = 0
        for c in paper_levels:
            pr = find(rows, "suite", explorer, c.key)
            dominated += any(
                find(rows, "suite", explorer, x.key)["success"] > pr["success"]
                and find(rows, "suite", explorer, x.key)["advice_per_100_steps"]
                <= pr["advice_per_100_steps"]
                for x in curve
            )
        less_advice = (
            g["advice_per_100_steps"] <= p["advice_per_100_steps"]
            and g["advice_per_task"] <= p["advice_per_task"]
        )
        first.append(
            {
                "explorer": explorer,
                "candidate": g["success"],
                "baseline": p["success"],
                "difference": diff[0],
                "difference_ci_low": diff[1],
                "difference_ci_high": diff[2],
                "candidate_advice_per_100": g["advice_per_100_steps"],
                "baseline_advice_per_100": p["advice_per_100_steps"],
                "candidate_advice_per_task": g["advice_per_task"],
                "baseline_advice_per_task": p["advice_per_task"],
                "baseline_levels_beaten": dominated,
                "baseline_levels": len(paper_levels),
                "met": diff[1] > 0 and less_advice,
            }
        )
    second = []
    for explorer in FIXED_EXPLORERS:
        none = find(rows, "suite", explorer, "none")
        if none["success"] < COMPETENT:
            continue
        for name, c in d.items():
            if name == "none":
                continue
            r = find(rows, "suite", explorer, c.key)
            second.append(
                {
                    "explorer": explorer,
                    "strategy": c.key,
                    "recommended": name == args.candidate,
                    "no_advice": none["success"],
                    "advised": r["success"],
                    "change": r["change_vs_none"],
                    "change_ci_low": r["change_vs_none_ci_low"],
                    "change_ci_high": r["change_vs_none_ci_high"],
                    "maps_worse": r["maps_worse"],
                    "not_lowered": r["change_vs_none"] >= 0,
                }
            )
    recommended = [x for x in second if x["recommended"]]
    return {
        "candidate": args.candidate,
        "baseline": args.baseline,
        "candidate_beats_baseline": first,
        "first_met": all(x["met"] for x in first),
        "competent": second,
        "recommended": ga.key,
        "second_met": all(x["not_lowered"] for x in recommended),
        "competent_threshold": COMPETENT,
    }


def task_rows(results: Results) -> list[dict[str, Any]]:
    """One row per map, explorer, configuration and task."""
    out = []
    for explorer, by_key in results.data.items():
        for key, m in by_key.items():
            for spec in results.maps:
                for i in range(m["success"].shape[1]):
                    out.append(
                        {
                            "map": spec.index,
                            "explorer": explorer,
                            "config": key,
                            "task": i,
                            **{name: float(v[spec.index, i]) for name, v in m.items()},
                        }
                    )
    return out


# ---- markdown ---------------------------------------------------------------------------
def pct(x: float) -> str:
    return f"{100 * x:.1f}"


def rate_ci(r: dict[str, Any]) -> str:
    return f"{pct(r['success'])} [{pct(r['success_ci_low'])}, {pct(r['success_ci_high'])}]"


def change(r: dict[str, Any], prefix: str = "change") -> str:
    mean, lo, hi = r[prefix], r[f"{prefix}_ci_low"], r[f"{prefix}_ci_high"]
    return f"{100 * mean:+.1f} [{100 * lo:+.1f}, {100 * hi:+.1f}]"


def verdict(r: dict[str, Any]) -> str:
    if r["change_vs_none_ci_low"] > 0:
        return "helps"
    if r["change_vs_none_ci_high"] < 0:
        return "hurts"
    return "no clear change"


def markdown(summary: dict[str, Any], args: Args, elapsed: float) -> str:
    rows: list[dict[str, Any]] = summary["rows"]
    configs = {r["key"]: r for r in rows}  # any scope: only the config fields are read
    curves = ("none", *args.strategies)
    default_keys = [r["key"] for r in rows if r["default"] and r["curve"] in curves]
    default_keys = list(dict.fromkeys(default_keys))
    parts = [settings_note(args, elapsed)]
    table = []
    for explorer in FIXED_EXPLORERS:
        for key in default_keys:
            s, f = find(rows, "suite", explorer, key), find(rows, "file", explorer, key)
            table.append(
                [
                    explorer,
                    short(configs[key]),
                    rate_ci(s),
                    f"{s['advice_per_100_steps']:.1f}",
                    f"{s['advice_per_task']:.0f}",
                    "—" if key == "none" else change(s, "change_vs_none"),
                    f"{s['trapped']}/{s['failures']}",
                    rate_ci(f),
                    f"{f['advice_per_100_steps']:.1f}",
                ]
            )
    parts.append(
        "**Default cost levels.** Success % [95% Wilson CI]; change vs no advice in percentage "
        "points, paired per task [95% CI].\n\n"
        + markdown_table(
            [
                "explorer",
                "strategy",
                "suite success %",
                "advice /100 steps",
                "advice /task",
                "change vs no advice",
                "trapped / failed",
                f"map `{args.maze.stem}` success %",
                f"map `{args.maze.stem}` advice /100",
            ],
            table,
        )
    )
    parts.append(helps_table(rows, default_keys, configs))
    parts.append(versus_table(summary["versus"], default_keys, configs, args.candidate))
    parts.append(kinds_table(rows, default_keys, configs))
    parts.append(targets_text(summary["targets"]))
    parts.append(sweep_table(rows))
    return "\n\n".join(parts) + "\n"


def short(r: dict[str, Any]) -> str:
    if r["curve"] == "none":
        return "no advice"
    if r["level_name"] == "" or (isinstance(r["level"], float) and math.isnan(r["level"])):
        return str(r["curve"])
    return f"{r['curve']} ({r['level_name']} {r['level']:g})"


def settings_note(args: Args, elapsed: float) -> str:
    n_perfect = (args.maps + 1) // 2
    return (
        f"Map suite: `{args.maze}` plus {args.maps} generated {args.map_size}x{args.map_size} "
        f"mazes ({n_perfect} perfect, {args.maps - n_perfect} braided {args.braid}), 8 goals "
        f"each; {args.tasks} tasks per map, explorer and configuration (the same tasks and "
        f"explorer streams for every configuration); one-shot limit {args.steps} steps; seed "
        f"{args.seed}; experts `{args.experts}` ({args.per_goal} per goal), alpha0 "
        f"{args.alpha0}, window {args.window}; strategies' parameters {base_params(args)}. "
        f"Q-learning not included. {elapsed:.0f} s with {args.workers} worker(s)."
    )


def helps_table(
    rows: list[dict[str, Any]], keys: list[str], configs: dict[str, dict[str, Any]]
) -> str:
    strategies = [k for k in keys if k != "none"]
    table = []
    for explorer in FIXED_EXPLORERS:
        none = find(rows, "suite", explorer, "none")
        cells = []
        for key in strategies:
            r = find(rows, "suite", explorer, key)
            cells.append(f"{verdict(r)} {100 * r['change_vs_none']:+.1f}")
        table.append([explorer, pct(none["success"]), *cells])
    header = ["explorer", "no advice %", *(short(configs[k]) for k in strategies)]
    return (
        "**Who advice helps and who it hurts** (suite, default levels): change in success "
        "(percentage points) against no advice; *helps* / *hurts* when the paired 95% interval "
        "excludes 0.\n\n" + markdown_table(header, table)
    )


def versus_table(
    versus: list[dict[str, Any]], keys: list[str], configs: dict[str, dict[str, Any]],
    candidate: str,
) -> str:  # fmt: skip
    others = [k for k in keys if configs[k]["curve"] != candidate]
    by = {(v["explorer"], v["other"]): v for v in versus}
    table = [
        [explorer, *(change(by[explorer, k], "difference") for k in others)]
        for explorer in FIXED_EXPLORERS
    ]
    cand = next(k for k in keys if configs[k]["curve"] == candidate)
    return (
        f"**{candidate} against every other default** (suite): success of "
        f"{short(configs[cand])} minus the other's, percentage points, paired per task "
        "[95% CI].\n\n" + markdown_table(["explorer", *(short(configs[k]) for k in others)], table)
    )


def kinds_table(
    rows: list[dict[str, Any]], keys: list[str], configs: dict[str, dict[str, Any]]
) -> str:
    table = []
    for explorer in FIXED_EXPLORERS:
        for key in keys:
            cells = []
            for scope in ("file", "perfect", "braided"):
                try:
                    r = find(rows, scope, explorer, key)
                except KeyError:
                    cells.append("—")
                    continue
                cells.append(f"{pct(r['success'])} / {r['advice_per_100_steps']:.1f}")
            table.append([explorer, short(configs[key]), *cells])
    return "**By kind of map** (success % / advice per 100 steps):\n\n" + markdown_table(
        ["explorer", "strategy", "file map", "perfect", "braided"], table
    )


def targets_text(t: dict[str, Any]) -> str:
    lines = [
        f"**Target 1** ({t['candidate']} vs {t['baseline']} at the default kappa, suite): "
        f"{'met' if t['first_met'] else 'NOT met'}.\n"
    ]
    table = [
        [
            x["explorer"],
            pct(x["baseline"]),
            pct(x["candidate"]),
            f"{100 * x['difference']:+.1f} [{100 * x['difference_ci_low']:+.1f}, "
            f"{100 * x['difference_ci_high']:+.1f}]",
            f"{x['baseline_advice_per_100']:.1f} → {x['candidate_advice_per_100']:.1f}",
            f"{x['baseline_advice_per_task']:.0f} → {x['candidate_advice_per_task']:.0f}",
            f"{x['baseline_levels_beaten']}/{x['baseline_levels']}",
            "met" if x["met"] else "not met",
        ]
        for x in t["candidate_beats_baseline"]
    ]
    lines.append(
        markdown_table(
            [
                "explorer",
                f"{t['baseline']} %",
                f"{t['candidate']} %",
                "difference, pp [95% CI]",
                f"advice /100 ({t['baseline']} → {t['candidate']})",
                "advice /task",
                f"{t['baseline']} levels beaten",
                "",
            ],
            table,
        )
    )
    lines.append(
        f"\n**Target 2** (the recommended default, `{t['recommended']}`, does not lower a "
        f"competent explorer's success, i.e. one with >= {100 * t['competent_threshold']:.0f}% "
        f"without advice): {'met' if t['second_met'] else 'NOT met'}. Every default strategy "
        "for the competent explorers:\n"
    )
    table = [
        [
            x["explorer"],
            x["strategy"] + (" (recommended)" if x["recommended"] else ""),
            pct(x["no_advice"]),
            pct(x["advised"]),
            change(x),
            x["maps_worse"],
        ]
        for x in t["competent"]
    ]
    lines.append(
        markdown_table(
            [
                "explorer",
                "strategy",
                "no advice %",
                "advised %",
                "change, pp [95% CI]",
                "maps where lower",
            ],
            table,
        )
    )
    return "\n".join(lines)


def sweep_table(rows: list[dict[str, Any]]) -> str:
    table = [
        [
            r["explorer"],
            short(r) + (" *" if r["default"] else ""),
            rate_ci(r),
            f"{r['advice_per_100_steps']:.1f}",
            f"{r['advice_per_task']:.0f}",
            f"{r['trapped']}/{r['failures']}",
        ]
        for r in rows
        if r["scope"] == "suite"
    ]
    return "**Every cost level** (suite; * default level):\n\n" + markdown_table(
        [
            "explorer",
            "strategy",
            "success % [95% CI]",
            "advice /100",
            "advice /task",
            "trapped / failed",
        ],
        table,
    )


# ---- plots ------------------------------------------------------------------------------
#: the curves' colours, in the order of the strategies compared
PALETTE = ("tab:blue", "tab:red", "tab:green", "tab:purple", "tab:brown", "tab:grey", "black",
           "tab:orange", "tab:olive", "tab:cyan", "tab:pink")  # fmt: skip


def plots(summary: dict[str, Any], args: Args) -> dict[str, Figure]:
    """Success against advice per 100 steps, one panel per explorer, one curve per strategy:
    for the whole suite and for the ``--maze`` map alone."""
    return {scope: plot(summary["rows"], scope, args) for scope in ("suite", "file")}


def plot(rows: list[dict[str, Any]], scope: str, args: Args) -> Figure:
    """One panel per explorer; each curve's points joined in order of advice given."""
    fig = Figure(figsize=(14, 8.4), layout="constrained")
    axes = fig.subplots(2, 3, sharex=True, sharey=True).ravel()
    for ax, explorer in zip(axes, FIXED_EXPLORERS, strict=False):
        mine = [r for r in rows if r["scope"] == scope and r["explorer"] == explorer]
        none = next(r for r in mine if r["curve"] == "none")
        ax.axhspan(100 * none["success_ci_low"], 100 * none["success_ci_high"], color="0.9")
        ax.axhline(100 * none["success"], color="0.4", ls="--", lw=1, label="no advice")
        for curve, colour in zip(args.strategies, itertools.cycle(PALETTE), strict=False):
            pts = sorted(
                (r for r in mine if r["curve"] == curve), key=lambda r: r["advice_per_100_steps"]
            )
            x = np.array([r["advice_per_100_steps"] for r in pts])
            y = np.array([100 * r["success"] for r in pts])
            low = y - np.array([100 * r["success_ci_low"] for r in pts])
            high = np.array([100 * r["success_ci_high"] for r in pts]) - y
            ax.errorbar(x, y, yerr=[low, high], color=colour, ms=4, lw=1.2, capsize=2,
                        marker="o" if len(pts) > 1 else "s", label=curve)  # fmt: skip
            for r, xi, yi in zip(pts, x, y, strict=True):
                if r["default"] and len(pts) > 1:
                    ax.plot(xi, yi, marker="*", ms=13, color=colour, mec="black", mew=0.6)
        ax.set_title(explorer)
        ax.grid(alpha=0.3)
        ax.set(xlim=(-2, 102), ylim=(0, 102))
    for ax in axes[len(FIXED_EXPLORERS) - 3 : len(FIXED_EXPLORERS)]:
        ax.set_xlabel("advice per 100 steps")
        ax.xaxis.set_tick_params(labelbottom=True)
    for ax in axes[::3]:
        ax.set_ylabel("success %")
    handles, labels = axes[0].get_legend_handles_labels()
    axes[-1].axis("off")
    axes[-1].legend(handles, labels, loc="center", fontsize=10, title="strategy")
    where = "the map suite" if scope == "suite" else f"map `{args.maze.stem}`"
    n_maps = args.maps + 1 if scope == "suite" else 1
    fig.suptitle(
        f"Success against advice given, {where}: {n_maps} map(s) x {args.tasks} tasks per "
        f"point; bars 95% Wilson CI; stars: default levels; grey band: no advice (95% CI)"
    )
    return fig


def run(args: Args, out: RunDir) -> dict[str, Any]:
    """Run the comparison and write JSON, CSV, markdown and PNG files."""
    args.check()
    results, elapsed = timed(run_all, args)
    summary = summarise(results, args)
    result = {
        **header("strategies", args, elapsed),
        "maps": [map_info(prepare_world(args, s)) for s in results.maps],
        "configs": [{"key": c.key, **asdict(c)} for c in results.configs],
        **summary,
    }
    out.json("strategies", result)
    out.csv("strategies", summary["rows"])
    out.csv("strategies_maps", summary["map_rows"])
    out.csv("strategies_versus", summary["versus"])
    out.csv("strategies_tasks", task_rows(results))
    out.markdown("strategies", markdown(summary, args, elapsed))
    for scope, fig in plots(summary, args).items():
        out.figure(f"strategies_{scope}", fig)
    return result
