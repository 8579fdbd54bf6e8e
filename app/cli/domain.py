"""``python -m app domain``: domains of a running service (``domain put NAME MAP.txt``).

The map file goes as it is (``text/plain``): whatever the project's commands write, ``maze
import`` (the resolution and origin of a ROS map as header lines) or ``maze generate``. The
service checks it as ``maze check`` does and refuses a bad one naming the line and column.
The service is found where ``serve`` listens (``ADVISOR_HOST``, ``ADVISOR_PORT``) and the
admin key where ``serve`` keeps it (``ADVISOR_ADMIN_KEY``, else ``<data_dir>/admin_key``),
unless ``--url`` and ``--key-file`` say otherwise; a key is never taken on the command line,
which other users of the machine can read.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from app.cli.local import URL_HELP, admin_key, service_url, settings_or_exit
from app.cli.options import choice

domain_cli = typer.Typer(help="Domains of a running service.", no_args_is_help=True)

EXPERTS = ("start", "anywhere")


def _fail(message: str) -> typer.Exit:
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(code=2)


@domain_cli.command("put")
def domain_put(
    name: Annotated[str, typer.Argument(help="The domain's name.")],
    map_file: Annotated[
        Path,
        typer.Argument(
            help="A map file as `maze import` or `maze generate` writes it (header lines "
            "resolution:, origin: and destination:, if any, then the rows).",
            show_default=False,
        ),
    ],
    experts: Annotated[
        str | None,
        choice(
            EXPERTS,
            "Learn the prior from simulated experts starting at the start or anywhere "
            "(a new domain or a new map only; default: none).",
        ),
    ] = None,
    per_goal: Annotated[
        int | None, typer.Option(min=1, max=1000, help="With --experts: walks per goal (10).")
    ] = None,
    seed: Annotated[
        int | None, typer.Option(min=0, help="With --experts: random seed (0).")
    ] = None,
    alpha0: Annotated[
        float | None, typer.Option(help="Dirichlet hyperprior alpha0 (default 1).")
    ] = None,
    url: Annotated[str | None, typer.Option(help=f"The service's URL ({URL_HELP}).")] = None,
    key_file: Annotated[
        Path | None,
        typer.Option(
            help="File holding the admin key (default: ADVISOR_ADMIN_KEY, else the data "
            "directory's admin_key, where serve keeps it)."
        ),
    ] = None,
    data_dir: Annotated[
        Path | None,
        typer.Option(help="The service's data directory, for its admin_key (ADVISOR_DATA_DIR)."),
    ] = None,
) -> None:
    """Create or replace a domain on a running service from a map file, sent as it is."""
    from advisor_client import AdvisorClient, AdvisorError

    if experts is None and (per_goal, seed) != (None, None):
        raise _fail("--per-goal and --seed go with --experts")
    settings = settings_or_exit(data_dir=data_dir)  # what serve reads
    url = url or service_url(settings)
    if key_file is not None:
        try:
            key: str | None = key_file.read_text(encoding="utf-8").strip()
        except OSError as exc:
            raise _fail(f"cannot read the key file {key_file}: {exc.strerror or exc}") from None
    else:
        key = admin_key(settings)
    if not key:
        raise _fail(
            "no admin key: set ADVISOR_ADMIN_KEY, give --key-file, or --data-dir of the "
            f"service (its admin_key; looked in {settings.data_dir})"
        )
    sent = {"source": experts, "per_goal": per_goal, "seed": seed}
    given = {k: v for k, v in sent.items() if v is not None} if experts else None
    try:
        with AdvisorClient(url, admin_key=key) as client:
            info = client.put_domain_file(name, map_file, alpha0, experts=given)
    except OSError as exc:  # reading the map file (the client's own failures are AdvisorError)
        raise _fail(f"cannot read {map_file}: {exc.strerror or exc}") from None
    except AdvisorError as exc:
        if exc.status == 0:
            raise _fail(exc.detail) from None
        if exc.detail.startswith("map: "):  # the map's problem, in maze check's words
            raise _fail(f"{map_file}: {exc.detail.removeprefix('map: ')}") from None
        raise _fail(f"the service refused {map_file} ({exc.status}): {exc.detail}") from None
    done = "created" if info["created_at"] == info["updated_at"] else "replaced"
    frame = f", cells of {info['resolution']:g} m" if info["resolution"] else ""
    typer.echo(
        f"{done} domain {info['name']!r} at {url}: {info['rows']}x{info['cols']}, "
        f"{info['n_states']} free cells, {len(info['goals'])} goals{frame}; prior from "
        f"{info['trajectories']} expert trajectories"
    )
