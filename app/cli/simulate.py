"""``python -m app simulate``: simulated explorers walk a domain through the live service.

Each explorer (:mod:`app.agents.explorers`) gets a random hidden goal per episode, opens a
session, and reports every move over the session's websocket with :mod:`advisor_client`. With
``--advice`` (the default) an advised explorer samples its next action from the advice
(the paper's protocol); with ``--no-advice`` the service still watches and decides, but the
explorer ignores it.
The map comes from the server (``GET /domains/{name}``, read by
:func:`app.domain.building.domain_of`: a map of several floors rebuilt from its floors and
connections, as the viewer rebuilds it); nothing here touches service internals.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from typing import Annotated

import httpx
import numpy as np
import numpy.typing as npt
import typer
from advisor_client import AdvisorError, AsyncAdvisorClient
from advisor_client.types import Decision
from tqdm import tqdm

from app import strategies
from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_STRATEGY, DEFAULT_WINDOW
from app.agents.explorers import FIXED_EXPLORERS, make_explorer
from app.cli.local import URL_HELP, service_url, settings_or_exit
from app.cli.options import choice
from app.domain.building import Domain, domain_of


@dataclass(frozen=True)
class Outcome:
    explorer: int
    episode: int
    goal: tuple[int, ...]
    success: bool
    steps: int
    advice_count: int
    p_normal: float


@dataclass(frozen=True)
class Plan:
    domain: str
    explorer: str
    advice: bool
    episodes: int
    explorers: int
    steps: int
    kappa: float
    window: int
    delay: float
    keep: bool
    strategy: str = DEFAULT_STRATEGY


def _advice(decision: Decision, grid: Domain) -> npt.NDArray[np.float64] | None:
    """The advice as a vector over the map's actions (N, E, S, W, and U, D on floors)."""
    given: dict[str, float] | None = decision["advice"]  # type: ignore[assignment]
    if given is None:
        return None
    return np.array([given[a] for a in grid.actions])


async def episode(
    client: AsyncAdvisorClient,
    grid: Domain,
    plan: Plan,
    k: int,
    e: int,
    rng: np.random.Generator,
) -> Outcome:
    """One task: a random goal, walked until reached or ``plan.steps`` moves."""
    goal = grid.goals[int(rng.integers(len(grid.goals)))]
    explorer = make_explorer(plan.explorer, grid)
    explorer.reset(goal, rng)
    s = grid.start
    session = await client.create_session(
        plan.domain,
        kappa=plan.kappa,
        window=plan.window,
        start=grid.cell(s),
        strategy=plan.strategy,
    )
    decision = session.decision
    steps = 0
    async with await client.stream(session) as stream:
        while steps < plan.steps and s != goal:
            advice = _advice(decision, grid) if plan.advice and decision["advise"] else None
            a = explorer.act(s, rng, advice)
            s2 = int(grid.next_state[s, a])
            explorer.observe(s, a, s2)
            event = {"state": grid.cell(s), "action": grid.actions[a], "next_state": grid.cell(s2)}
            decision = await stream.send(event)
            s, steps = s2, steps + 1
            if plan.delay:
                await asyncio.sleep(plan.delay)
    if not plan.keep:
        await client.end_session(session)
    cost = decision["cost"]
    return Outcome(
        k, e, grid.cell(goal), s == goal, steps, cost["advice_count"], decision["p_normal"]
    )


def line(o: Outcome) -> str:
    return (
        f"episode {o.episode} (explorer {o.explorer}): goal {list(o.goal)} "
        f"{'reached' if o.success else 'not reached'} in {o.steps} steps, "
        f"{o.advice_count} advice, P(M1|H) {o.p_normal:.3f}"
    )


async def run(server: str, plan: Plan, seed: int, progress: bool = True) -> list[Outcome]:
    """All episodes, ``plan.explorers`` at a time (explorer k runs episodes k, k+K, ...);
    each episode's line is printed in episode order, as soon as those before it are done."""
    async with AsyncAdvisorClient(server) as client:
        info = await client.domain(plan.domain)
        grid = domain_of(dict(info), plan.domain)
        rngs = np.random.default_rng(seed).spawn(plan.explorers)
        done: dict[int, Outcome] = {}
        printed = 0
        bar = tqdm(total=plan.episodes, unit="episode", disable=not progress, leave=False)

        async def worker(k: int) -> None:
            nonlocal printed
            for e in range(k, plan.episodes, plan.explorers):
                done[e] = await episode(client, grid, plan, k, e, rngs[k])
                bar.update(1)
                while printed in done:
                    bar.write(line(done[printed]))
                    printed += 1

        try:
            await asyncio.gather(*(worker(k) for k in range(plan.explorers)))
        finally:
            bar.close()
    return [done[e] for e in sorted(done)]


def summary(outcomes: list[Outcome], plan: Plan) -> str:
    n = len(outcomes)
    wins = sum(o.success for o in outcomes)
    steps = sum(o.steps for o in outcomes)
    advice = sum(o.advice_count for o in outcomes)
    per100 = 100.0 * advice / max(1, steps + n)  # one decision per step, plus each start
    return (
        f"{plan.explorer}, advice {'on' if plan.advice else 'off'} ({plan.strategy}), "
        f"kappa {plan.kappa}: "
        f"{wins}/{n} reached their goal (mean reward {1000.0 * wins / max(1, n):.0f}); "
        f"mean steps {steps / max(1, n):.1f}; advice per 100 decisions {per100:.1f}"
    )


def simulate(
    server: Annotated[str | None, typer.Option(help=f"Service URL ({URL_HELP}).")] = None,
    explorer: Annotated[str, choice(FIXED_EXPLORERS, "The simulated explorer.")] = "random",
    advice: Annotated[
        bool,
        typer.Option(
            "--advice/--no-advice", help="Advised explorers follow the advice (or ignore it)."
        ),
    ] = True,
    episodes: Annotated[int, typer.Option(min=1, help="Episodes (tasks) in all.")] = 10,
    explorers: Annotated[int, typer.Option(min=1, help="Explorers walking at once.")] = 1,
    steps: Annotated[int, typer.Option(min=1, help="Moves per episode at most.")] = 5000,
    kappa: Annotated[
        float, typer.Option(min=0.0, help="Cost of one piece of advice.")
    ] = DEFAULT_KAPPA,
    window: Annotated[int, typer.Option(min=1, help="History window W.")] = DEFAULT_WINDOW,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    domain: Annotated[str, typer.Option(help="Domain to walk.")] = "default",
    delay: Annotated[float, typer.Option(min=0.0, help="Seconds between moves (to watch).")] = 0.0,
    keep: Annotated[bool, typer.Option(help="Leave sessions open after each episode.")] = False,
    strategy: Annotated[
        str, choice(strategies.names(), "When to advise (the strategy's default parameters).")
    ] = DEFAULT_STRATEGY,
    progress: Annotated[bool, typer.Option(help="A progress bar (on stderr).")] = True,
) -> None:
    """Drive simulated explorers through the live service and print their outcomes."""
    server = server or service_url(settings_or_exit())  # where serve listens
    plan = Plan(
        domain, explorer, advice, episodes, explorers, steps, kappa, window, delay, keep, strategy,
    )  # fmt: skip
    try:
        outcomes = asyncio.run(run(server, plan, seed, progress))
    except AdvisorError as exc:
        reason = exc.detail if exc.status == 0 else f"the service refused: {exc}"
        typer.echo(f"error: {reason}", err=True)
        raise typer.Exit(code=2) from None
    except (httpx.HTTPError, OSError) as exc:
        typer.echo(f"error: cannot reach {server}: {exc}", err=True)
        raise typer.Exit(code=2) from None
    typer.echo(summary(outcomes, plan))
