from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from app.cli import cli
from app.domain.grid import GridDomain

runner = CliRunner()


def test_cli_help_lists_working_commands() -> None:
    result = runner.invoke(cli, ["--help"])
    assert result.exit_code == 0
    for command in ("maze", "train"):
        assert command in result.output


def test_cli_maze_show_prints_default_map_and_goals() -> None:
    result = runner.invoke(cli, ["maze", "show"])
    assert result.exit_code == 0
    assert result.output.startswith("G....#")
    assert "30x30, 455 free cells" in result.output
    assert "start [28, 0]" in result.output


def test_cli_maze_check_accepts_valid_and_rejects_bad_map(tmp_path: Path) -> None:
    good = tmp_path / "good.txt"
    good.write_text("S.G\n...\n")
    result = runner.invoke(cli, ["maze", "check", str(good)])
    assert result.exit_code == 0
    assert result.output.startswith("ok: good: 2x3")
    bad = tmp_path / "bad.txt"
    bad.write_text("S.G\n.#\n")
    result = runner.invoke(cli, ["maze", "check", str(bad)])
    assert result.exit_code == 2
    assert "line 2: ragged row" in result.output


def test_cli_maze_generate_writes_a_valid_reproducible_map(tmp_path: Path) -> None:
    out = tmp_path / "gen.txt"
    args = ["maze", "generate", "--rows", "15", "--cols", "21", "--seed", "4", "--braid", "0.5"]
    result = runner.invoke(cli, [*args, "--out", str(out)])
    assert result.exit_code == 0
    d = GridDomain.from_file(out)
    assert d.shape == (15, 21) and len(d.goals) == 8
    printed = runner.invoke(cli, args)
    assert printed.output == out.read_text()


def test_cli_maze_generate_rejects_impossible_request() -> None:
    result = runner.invoke(cli, ["maze", "generate", "--rows", "3", "--cols", "3"])
    assert result.exit_code == 2
    assert "room for only" in result.output


def test_cli_train_prints_prior_and_direction_map() -> None:
    result = runner.invoke(cli, ["train", "--per-goal", "2"])
    assert result.exit_code == 0, result.output
    assert "prior: 16 expert trajectories (start)" in result.output
    assert "most advised direction" in result.output
    # the start cell's row in the direction map: experts all leave the start going east
    assert "S>>>>>" in result.output


def test_cli_train_policy_source_counts_every_state() -> None:
    result = runner.invoke(cli, ["train", "--experts", "policy", "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)
    assert summary["trajectories"] == 8
    # every state lies on an optimal path to at least one goal in a connected maze
    assert summary["states_with_data"] == summary["states"]


def test_cli_train_rejects_unknown_expert_source(tmp_path: Path) -> None:
    result = runner.invoke(cli, ["train", "--experts", "nobody"])
    assert result.exit_code == 2
    assert "--experts must be one of start, anywhere, policy" in result.output


def test_cli_train_reports_bad_map_with_location(tmp_path: Path) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_text("S.G\n.x.\n")
    result = runner.invoke(cli, ["train", "--maze", str(bad)])
    assert result.exit_code == 2
    assert "line 2, column 2: unknown character 'x'" in result.output
