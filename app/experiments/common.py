"""What every experiment shares: its common arguments, the setup they produce, seeding, stats.

Seeding: one ``--seed`` makes everything reproducible. Each random stream is its own
``np.random.Generator`` keyed by what it is for (``rng_for(seed, "table1", explorer, advised,
task)``), so adding a run never shifts the randomness of another.
"""

from __future__ import annotations

import math
import multiprocessing
import time
import zlib
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

import numpy as np
import numpy.typing as npt
from tqdm import tqdm

from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_WINDOW
from app.advice.models import AdviceTables
from app.advice.priors import ActionPrior
from app.agents.experts import EXPERT_SOURCES, ExpertSource, train_prior
from app.agents.simulate import QParams, Simulator
from app.arrays import FloatArray, IntArray
from app.domain.grid import GridDomain
from app.domain.maps import DEFAULT_MAP

Job = TypeVar("Job", bound=tuple[Any, ...])
Got = TypeVar("Got")
Given = TypeVar("Given")


def timed(work: Callable[[Given], Got], args: Given) -> tuple[Got, float]:
    """``work(args)`` and the seconds it took (an experiment's runs, for its header)."""
    started = time.perf_counter()
    got = work(args)
    return got, time.perf_counter() - started


def run_jobs(
    jobs: Sequence[Job],
    work: Callable[..., Got],
    done: Callable[[Job, Got], None],
    workers: int,
    desc: str,
    progress: bool,
) -> None:
    """``work(*job)`` for every job, here (``workers`` 1) or in that many spawned processes
    (``work`` and the jobs must pickle), ``done(job, result)`` as each finishes, under a
    progress bar."""
    with tqdm(total=len(jobs), desc=desc, unit="job", disable=not progress) as bar:
        if workers == 1:
            for job in jobs:
                done(job, work(*job))
                bar.update()
            return
        ctx = multiprocessing.get_context("spawn")  # no fork of a process with threads
        with ProcessPoolExecutor(workers, mp_context=ctx) as pool:
            futures = {pool.submit(work, *job): job for job in jobs}
            for fut in as_completed(futures):
                done(futures[fut], fut.result())
                bar.update()


def fill(
    into: dict[str, dict[str, FloatArray]], got: dict[str, dict[str, FloatArray]], row: int
) -> None:
    """One map's measures (``got[config key][measure]``, a value per task) into row ``row`` of
    ``into``'s arrays (one row per map, one column per task)."""
    for key, measures in got.items():
        for name, values in measures.items():
            into[key][name][row] = values


@dataclass
class CommonArgs:
    """Arguments every experiment takes (the paper's protocol by default)."""

    maze: Path = DEFAULT_MAP
    """ASCII map file ('#' wall, '.' free, 'S' start, 'G' goals)."""
    seed: int = 0
    """Seeds every random choice (expert data, task goals, explorers)."""
    tasks: int = 20
    """Random one-shot tasks (goal drawn uniformly from the map's goals) per explorer."""
    kappa: float = DEFAULT_KAPPA
    """Cost of one piece of advice: advise iff KL[theta_s || P(A|s,H)] >= kappa (nats)."""
    alpha0: float = 1.0
    """Dirichlet hyperprior: pseudo-count added to every action of every state."""
    window: int = DEFAULT_WINDOW
    """Length W of the history H the posterior P(M|H) is computed over."""
    experts: ExpertSource = "start"
    """Expert data: 'start' (trajectories from the start cell, as every agent in the paper
    starts there), 'anywhere' (from random cells) or 'policy' (full optimal policies)."""
    per_goal: int = 10
    """Expert trajectories per goal (ignored for 'policy')."""
    progress: bool = True
    """Show tqdm progress bars."""

    def check(self) -> None:
        """Raise ValueError naming the first argument that is out of range."""
        if self.experts not in EXPERT_SOURCES:
            raise ValueError(f"experts must be one of {', '.join(EXPERT_SOURCES)}")
        if self.tasks < 1 or self.per_goal < 1:
            raise ValueError("tasks and per-goal must be at least 1")
        if not (math.isfinite(self.kappa) and self.kappa >= 0):
            raise ValueError(f"kappa must be a finite number >= 0, got {self.kappa}")
        if not (math.isfinite(self.alpha0) and self.alpha0 > 0):
            raise ValueError(f"alpha0 must be > 0, got {self.alpha0}")
        if self.window < 1:
            raise ValueError(f"window must be at least 1, got {self.window}")
        if isinstance(self, LearningArgs):
            self.q_params()  # validates the Q-learner's settings

    def check_trajectories(self, experiment: str) -> None:
        """ValueError unless the experts are trajectories (the goal of each is needed)."""
        if self.experts == "policy":
            raise ValueError(f"{experiment} needs expert trajectories: experts start or anywhere")

    def prior_settings(self) -> dict[str, object]:
        return {
            "maze": str(self.maze),
            "seed": self.seed,
            "experts": self.experts,
            "per_goal": self.per_goal,
            "alpha0": self.alpha0,
        }


def rng_for(seed: int, *keys: str | int | bool) -> np.random.Generator:
    """An independent generator for the stream named by ``keys`` under ``seed``."""
    key = tuple(
        zlib.crc32(k.encode()) if isinstance(k, str) else int(k) for k in keys
    )  # strings hash stably across runs (unlike hash())
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


@dataclass
class Setup:
    """The maze, the learned prior, and the compiled simulator for one set of arguments."""

    domain: GridDomain
    prior: ActionPrior
    tables: AdviceTables
    sim: Simulator
    goals: IntArray = field(repr=False)  # the goal of each task

    def goal_index(self, goal: int) -> int:
        return self.domain.goals.index(goal)


def prepare(args: CommonArgs, n_tasks: int | None = None) -> Setup:
    """Load the maze, learn the prior from experts, draw the tasks' goals."""
    args.check()
    domain = GridDomain.from_file(args.maze)
    prior = train_prior(
        domain,
        rng_for(args.seed, "experts"),
        args.experts,
        args.per_goal,
        args.alpha0,
    )
    tables = AdviceTables.paper(prior.theta())
    n = args.tasks if n_tasks is None else n_tasks
    goals = rng_for(args.seed, "tasks").choice(np.array(domain.goals, dtype=np.int64), size=n)
    return Setup(domain, prior, tables, Simulator(domain, tables), goals)


def wilson(successes: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval for a success rate (95% by default); (0, 1) when n = 0."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    # exactly 0 / 1 at the ends (as the formula gives without rounding), else clipped
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == n else min(1.0, centre + half)
    return low, high


def moving_average(x: npt.ArrayLike, width: int) -> FloatArray:
    """Centred moving average ignoring NaN; the ends average over what is there."""
    arr = np.asarray(x, dtype=np.float64)
    if width <= 1 or arr.size == 0:
        return arr.copy()
    ok = np.isfinite(arr)
    kernel = np.ones(min(width, arr.size))  # np.convolve "same" is as long as the longer input
    total = np.convolve(np.where(ok, arr, 0.0), kernel, mode="same")
    count = np.convolve(ok.astype(np.float64), kernel, mode="same")
    out: FloatArray = np.divide(total, count, out=np.full_like(total, np.nan), where=count > 0)
    return out


@dataclass
class LearningArgs:
    """Arguments of the Q-learning explorer (Figure 6, and its row of Table I)."""

    episodes: int = 5000
    """Q-learning episodes per task."""
    episode_steps: int = 200
    """Step limit of one Q-learning episode."""
    q_alpha: float = 0.1
    """Q-learning step size (Sutton & Barto's usual value)."""
    q_gamma: float = 0.95
    """Discount factor."""
    q_epsilon: float = 0.1
    """Exploration probability; exploring samples the advice when advice is given."""
    q_ties: Literal["advice", "uniform"] = "advice"
    """How equal Q-values are broken: 'advice' (sample the advice among them when advised)
    or 'uniform'. Until a reward reaches a state all four tie, so this matters."""
    q_keep_history: bool = True
    """The advisor's window carries over between episodes of one learner (it watches the
    same explorer; the window, 300, is longer than an episode, 200). Off: every episode is
    a new advisor session."""

    def q_params(self) -> QParams:
        return QParams(self.q_alpha, self.q_gamma, self.q_epsilon, self.q_ties)

    def learning_settings(self) -> dict[str, object]:
        return {
            "episodes": self.episodes,
            "episode_steps": self.episode_steps,
            "q_alpha": self.q_alpha,
            "q_gamma": self.q_gamma,
            "q_epsilon": self.q_epsilon,
            "q_ties": self.q_ties,
            "q_keep_history": self.q_keep_history,
        }
