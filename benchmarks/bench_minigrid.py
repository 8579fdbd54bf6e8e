"""MiniGrid with and without advice: a random explorer on FourRooms and MultiRoom.

The service runs as a subprocess (``python -m app serve --no-viewer``, fresh data directory);
each episode is one layout seed, the same seeds with and without advice (paired). The explorer
picks uniformly among the compass actions (:class:`advisor_client.minigrid.CompassActions`);
advised (``AdvisedMiniGrid(..., follow_advice=True)``), it samples from the advice instead
whenever the service advises. An episode succeeds when MiniGrid says it reached the goal
before its own step limit (FourRooms 100 steps, MultiRoom-N4-S5 80). Advised runs are
repeated for each ``--kappa`` (0.2 and 0.5 by default); the walks alone do not depend on it.

    .venv/bin/python benchmarks/bench_minigrid.py [--episodes 100] [--kappa 0.2 0.5]
        [--write docs/RESULTS.md]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from advisor_client import AdvisorClient  # noqa: E402
from advisor_client.minigrid import AdvisedMiniGrid, CompassActions  # noqa: E402

from benchmarks._load import start_advisor  # noqa: E402
from benchmarks._report import arguments, command_line, machine, write_section  # noqa: E402

ENVS = ("MiniGrid-FourRooms-v0", "MiniGrid-MultiRoom-N4-S5-v1")


def episode(env: gym.Env[Any, Any], seed: int) -> tuple[bool, int, int]:
    """(reached the goal, steps, pieces of advice) for one random walk on layout ``seed``."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    steps = advice = 0
    while True:
        _, reward, terminated, truncated, info = env.step(int(rng.integers(4)))
        steps += 1
        advice += bool(info.get("decision", {}).get("advise", False))
        if terminated or truncated:
            return bool(terminated and float(reward) > 0), steps, advice


def run(
    url: str, key: str, episodes: int, kappas: list[float]
) -> dict[tuple[str, float], dict[str, float]]:
    """Per (environment, kappa): success alone and advised, mean steps, advice per 100 steps."""
    out: dict[tuple[str, float], dict[str, float]] = {}
    with AdvisorClient(url, admin_key=key) as client:
        for env_id in ENVS:
            alone = CompassActions(gym.make(env_id))
            a = [episode(alone, s) for s in range(episodes)]
            for kappa in kappas:
                advised = AdvisedMiniGrid(gym.make(env_id), client, kappa=kappa, follow_advice=True)
                b = [episode(advised, s) for s in range(episodes)]
                advised.close()
                out[env_id, kappa] = {
                    "alone": sum(x[0] for x in a) / episodes,
                    "advised": sum(x[0] for x in b) / episodes,
                    "alone_steps": float(np.mean([x[1] for x in a])),
                    "advised_steps": float(np.mean([x[1] for x in b])),
                    "advice_per_100": 100.0 * sum(x[2] for x in b) / sum(x[1] for x in b),
                }
    return out


def report(args: argparse.Namespace, res: dict[tuple[str, float], dict[str, float]]) -> str:
    rows = [
        f"| {env_id} | {kappa:g} | {r['alone']:.0%} ({r['alone_steps']:.0f}) | "
        f"{r['advised']:.0%} ({r['advised_steps']:.0f}) | {r['advice_per_100']:.0f} |"
        for (env_id, kappa), r in res.items()
    ]
    return "\n".join([
        "## MiniGrid: a random explorer with and without advice",
        "",
        f"Command: `{command_line()}`  ",
        f"Machine: {machine()}.",
        "",
        f"{args.episodes} episodes per environment, layout seeds 0-{args.episodes - 1}, the "
        "same with and without advice (the walks alone do not depend on kappa); each "
        "layout's domain learned from the adapter's simulated experts (from anywhere, 100 per "
        "goal).",
        "",
        "| environment | kappa | reached the goal alone (mean steps) | advised (mean steps) "
        "| advice per 100 steps |",
        "|---|---|---|---|---|",
        *rows,
    ]) + "\n"  # fmt: skip


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--kappa", type=float, nargs="+", default=[0.2, 0.5])
    ap.add_argument("--write", type=Path)
    args = ap.parse_args()
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    with (
        tempfile.TemporaryDirectory(prefix="bench-minigrid-") as tmp,
        start_advisor(Path(tmp)) as server,
    ):
        res = run(server.url, "bench", args.episodes, args.kappa)
    body = report(args, res)
    print(body)
    if args.write:
        write_section(args.write, "bench_minigrid", body)


if __name__ == "__main__":
    main()
