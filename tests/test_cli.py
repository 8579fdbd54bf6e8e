from __future__ import annotations

import json
import socket
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

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


def test_cli_maze_check_and_show_name_the_destinations(tmp_path: Path) -> None:
    named = tmp_path / "named.txt"
    named.write_text("destination: 0 2 Lecture hall B\nS.G\n..G\n")
    result = runner.invoke(cli, ["maze", "check", str(named)])
    assert result.exit_code == 0, result.output
    assert "G0[0, 2] 'Lecture hall B' at 2, G1[1, 2] at 3" in result.output
    shown = runner.invoke(cli, ["maze", "show", str(named)])
    assert shown.output.startswith("S.G\n..G\n") and "'Lecture hall B'" in shown.output
    named.write_text("destination: 0 2 Lecture hall B\ndestination: 1 0 Hall\nS.G\n..G\n")
    result = runner.invoke(cli, ["maze", "check", str(named)])
    assert result.exit_code == 2
    assert "line 2, column 14: cell [1, 0] is a free cell, not a destination" in result.output


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
    result = runner.invoke(cli, ["train", "--experts", "nobody"], env={"COLUMNS": "200"})
    assert result.exit_code == 2
    assert "'nobody' is not one of 'start', 'anywhere', 'policy'" in result.output


def test_cli_train_reports_bad_map_with_location(tmp_path: Path) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_text("S.G\n.x.\n")
    result = runner.invoke(cli, ["train", "--maze", str(bad)])
    assert result.exit_code == 2
    assert "line 2, column 2: unknown character 'x'" in result.output


def test_cli_version() -> None:
    result = runner.invoke(cli, ["--version"])
    assert result.exit_code == 0 and result.output.startswith("advisor ")


def test_cli_help_shows_flags_as_flags_and_lists_choices() -> None:
    result = runner.invoke(cli, ["simulate", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    assert "<bool>" not in result.output
    assert "<random|random-avoid|left|bug|optimal>" in result.output
    assert "--advice" in result.output and "--no-advice" in result.output
    train = runner.invoke(cli, ["train", "--help"], env={"COLUMNS": "200"})
    assert "<start|anywhere|policy>" in train.output
    assert "app/domain/maps/default.txt" in train.output and "..." not in train.output


def test_cli_refusals_say_what_is_allowed_without_pydantics_prefix() -> None:
    wide = {"COLUMNS": "200"}
    zero = runner.invoke(cli, ["train", "--alpha0", "0"], env=wide)
    assert zero.exit_code == 2 and "0.0 is not > 0" in zero.output
    source = runner.invoke(cli, ["experiment", "table1", "--experts", "x"], env=wide)
    assert source.exit_code == 2 and "'x' is not one of 'start', 'anywhere', 'policy'" in (
        source.output
    )
    port = runner.invoke(cli, ["serve", "--port", "99999"], env=wide)
    assert port.exit_code == 2 and "port (ADVISOR_PORT): Input should be" in port.output
    for result in (zero, source, port):
        assert "Value error" not in result.output


def test_cli_serve_finds_a_busy_port_before_creating_anything(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        data = tmp_path / "data"
        result = runner.invoke(cli, ["serve", "--port", str(port), "--data-dir", str(data)])
    assert result.exit_code == 2 and f"port {port} on 127.0.0.1 is in use" in result.output
    assert not data.exists()  # no data directory, no admin key


def test_cli_serve_refuses_workers_without_redis(tmp_path: Path) -> None:
    data = tmp_path / "data"
    result = runner.invoke(cli, ["serve", "--workers", "2", "--data-dir", str(data)], env={})
    assert result.exit_code == 2
    assert "error: bad setting: workers 2 needs ADVISOR_REDIS_URL" in result.output
    assert not data.exists()


def test_cli_serve_refuses_an_unknown_log_level_before_creating_anything(
    tmp_path: Path,
) -> None:
    data = tmp_path / "data"
    wide = {"COLUMNS": "200"}
    result = runner.invoke(cli, ["serve", "--log-level", "foo", "--data-dir", str(data)], env=wide)
    assert result.exit_code == 2
    assert "'foo' is not one of 'critical', 'error', 'warning', 'info', 'debug', 'trace'" in (
        result.output
    )
    assert result.exception is None or isinstance(result.exception, SystemExit)  # no traceback
    assert not data.exists()  # no data directory, no keys
    shown = runner.invoke(cli, ["serve", "--help"], env=wide).output
    assert "<critical|error|warning|info|debug|trace>" in shown


def test_cli_log_levels_are_uvicorns() -> None:
    from uvicorn.config import LOG_LEVELS as UVICORN

    from app.cli.serve import LOG_LEVELS

    assert set(LOG_LEVELS) == set(UVICORN)


def command_paths() -> list[list[str]]:
    """Every command and subcommand of the command line, as the words that name it."""
    import typer

    paths: list[list[str]] = []

    def walk(command: Any, path: list[str]) -> None:  # typer's click command or group
        paths.append(path)
        if hasattr(command, "list_commands"):  # a group (experiment's are made when asked)
            for name in command.list_commands(None):
                walk(command.get_command(None, name), [*path, name])

    walk(typer.main.get_command(cli), [])
    return paths


def test_every_help_reads_whole_at_80_columns() -> None:
    """No default (a URL, a path) is cut with an ellipsis: long ones wrap onto the next line."""
    paths = command_paths()
    assert ["serve"] in paths and ["maze", "generate"] in paths and ["experiment", "all"] in paths
    for path in paths:
        result = runner.invoke(cli, [*path, "--help"], env={"COLUMNS": "80"})
        assert result.exit_code == 0, (path, result.output)
        assert "…" not in result.output, (path, result.output)
        assert max(len(line) for line in result.output.splitlines()) <= 80, path
    simulate = runner.invoke(cli, ["simulate", "--help"], env={"COLUMNS": "80"}).output
    assert "http://127.0.0.1:8000" in simulate
    train = runner.invoke(cli, ["train", "--help"], env={"COLUMNS": "80"}).output
    column = "".join(line[50:].strip(" │") for line in train.splitlines() if "│" in line)
    assert "(app/domain/maps/default.txt)" in column


def test_cli_serve_finds_the_viewers_busy_port_and_names_its_option(tmp_path: Path) -> None:
    """The viewer's port is checked with the API's, before anything is created: the refusal
    names the port, the option and the setting that move it."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        data = tmp_path / "data"
        args = ["serve", "--port", "0", "--viewer-port", str(port), "--data-dir", str(data)]
        result = runner.invoke(cli, args, env={"COLUMNS": "200"})
    assert result.exit_code == 2, result.output
    assert f"the 3D viewer's port {port} on 127.0.0.1 is in use" in result.output
    assert "--viewer-port or ADVISOR_VIEWER_PORT" in result.output
    assert "--no-viewer" in result.output
    assert not data.exists()
    same = runner.invoke(cli, ["serve", "--port", "8123", "--viewer-port", "8123"])
    assert same.exit_code == 2 and "both want port 8123" in same.output


def test_cli_serve_names_the_api_ports_option(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = runner.invoke(cli, ["serve", "--port", str(port), "--no-viewer"])
    assert result.exit_code == 2
    assert "pick another port with --port or ADVISOR_PORT" in result.output


def test_cli_clients_read_the_service_address_serve_reads(monkeypatch: Any) -> None:
    """simulate and viewer call the service where serve listens: ADVISOR_HOST and
    ADVISOR_PORT (an address of every interface is called on loopback)."""
    from app.cli.local import service_url, settings_or_exit

    monkeypatch.setenv("ADVISOR_PORT", "8123")
    assert service_url(settings_or_exit()) == "http://127.0.0.1:8123"
    monkeypatch.setenv("ADVISOR_HOST", "0.0.0.0")
    assert service_url(settings_or_exit()) == "http://127.0.0.1:8123"
    monkeypatch.setenv("ADVISOR_HOST", "::1")
    assert service_url(settings_or_exit()) == "http://[::1]:8123"


def test_cli_simulate_calls_the_port_of_advisor_port() -> None:
    """Nothing listens on the port ADVISOR_PORT names: simulate says it could not reach that
    URL (not :8000)."""
    with socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]  # bound, never listening: connections are refused
        env = {"ADVISOR_PORT": str(port), "COLUMNS": "200"}
        args = ["simulate", "--episodes", "1", "--no-progress"]
        # in a thread of its own: simulate runs asyncio, and the browser tests' Playwright keeps
        # a loop running in this one (a user's process has none)
        with ThreadPoolExecutor(1) as pool:
            result = pool.submit(runner.invoke, cli, args, env=env).result()
    assert result.exit_code == 2, result.output
    assert f"http://127.0.0.1:{port}" in result.output


FLOORS = """\
destination: 1 1 3 Roof garden
connection: lift 4 0:1,1 1:1,1 Lift 1
connection: stairs 6 0:1,3 1:1,1 Stairs A
floor: 0 Ground floor elevation: 0.0
#####
#.S.#
#####
floor: 1 Roof elevation: 3.5
#####
#..G#
#####
"""


def test_cli_maze_check_and_show_read_a_map_of_several_floors(tmp_path: Path) -> None:
    path = tmp_path / "tower.txt"
    path.write_text(FLOORS)
    checked = runner.invoke(cli, ["maze", "check", str(path)])
    assert checked.exit_code == 2  # the stairs' top stop is the lift's
    assert checked.output == (
        f"error: {path}: line 3, column 28: connection 'Stairs A': stop [1, 1] on floor 1 "
        "'Roof' is a stop of 'Lift 1' too: a cell is a stop of one connection at most\n"
    )
    path.write_text(FLOORS.replace("1:1,1 Stairs", "1:1,2 Stairs"))
    checked = runner.invoke(cli, ["maze", "check", str(path)])
    assert checked.exit_code == 0, checked.output
    assert checked.output.startswith(
        "ok: tower: 2 floors of 3x5 (ordinals 0 to 1), 6 free cells, 2 connection(s), start "
        "[0, 1, 2] on floor 0 'Ground floor'\n"
    )
    # W to the lift, U (4 moves of time), E E: 7; by the stairs: E, U (6), E: 8
    assert "G0[1, 1, 3] 'Roof garden' at 7" in checked.output
    shown = runner.invoke(cli, ["maze", "show", str(path)])
    assert shown.exit_code == 0, shown.output
    assert shown.output.startswith(
        "floor 0 'Ground floor' (floor 0 of the cells, elevation 0 m)\n#####\n#ASB#\n#####\n\n"
        "floor 1 'Roof' (floor 1 of the cells, elevation 3.5 m)\n#####\n#ABG#\n#####\n\n"
        "A  lift 'Lift 1', 4 moves a floor: floors 0, 1 at [1, 1]\n"
        "B  stairs 'Stairs A', 6 moves a floor: 0:[1, 3] 1:[1, 2]\n"
    )
    trained = runner.invoke(cli, ["train", "--maze", str(path)])
    assert trained.exit_code == 0, trained.output
    # the experts take the lift (7 moves of time, the stairs 8): W, U, then E E upstairs
    assert "nats (uniform over 6 actions 1.792)" in trained.output
    assert trained.output.endswith(
        "floor 0 'Ground floor'\n#####\n#US·#\n#####\n\nfloor 1 'Roof'\n#####\n#>>G#\n#####\n"
    )


def test_cli_maze_generate_buildings_of_several_floors(tmp_path: Path) -> None:
    out = tmp_path / "clinic.txt"
    args = ["maze", "generate", "--kind", "building", "--floors", "3", "--rows", "30",
            "--cols", "40", "--purpose", "hospital", "--goals", "4", "--seed", "2"]  # fmt: skip
    result = runner.invoke(cli, [*args, "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert result.output.startswith("wrote ") and "clinic: 3 floors of 30x40" in result.output
    checked = runner.invoke(cli, ["maze", "check", str(out)])
    assert checked.exit_code == 0 and "4 connection(s)" in checked.output
    text = out.read_text()
    assert text.count("\nfloor: ") + text.startswith("floor: ") == 3
    assert text.count("connection: lift 12 0:") == 2 and text.count("connection: stairs 18") == 2
    assert text.count("destination: ") == 12
    assert runner.invoke(cli, args).output == text  # the same seed, the same building
    # one floor: the building of before, no floor lines
    one = runner.invoke(cli, ["maze", "generate", "--kind", "building", "--seed", "2"])
    assert one.exit_code == 0 and "floor:" not in one.output
    for wrong, said in ((["--floors", "2"], "--floors is for --kind building"),
                        (["--kind", "building", "--floors", "2", "--rows", "12", "--cols", "12"],
                         "a 12x12 plan has no corridor")):  # fmt: skip
        refused = runner.invoke(cli, ["maze", "generate", *wrong])
        assert refused.exit_code == 2 and said in refused.output
