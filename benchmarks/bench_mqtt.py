"""Decisions per second through an MQTT broker (the service's bridge, QoS 1 both ways).

A Mosquitto broker of its own on a free port, the service as a subprocess (``python -m app
serve --no-viewer`` with ``ADVISOR_MQTT_URL``), and one asyncio process here that publishes
events for ``--explorers`` explorers (random walks on the shipped maze) and counts the
decisions coming back, one MQTT message each; the rate is decisions received over the time from
the first event published to the last decision received. Twice: one event per message, and
``--batch`` events per message.

    .venv/bin/python benchmarks/bench_mqtt.py [--write docs/PERFORMANCE.md]
"""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import aiomqtt
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.domain.grid import ACTIONS, GridDomain  # noqa: E402
from app.domain.maps import DEFAULT_MAP  # noqa: E402
from benchmarks._load import free_port, start_advisor  # noqa: E402
from benchmarks._report import arguments, command_line, machine, write_section  # noqa: E402

MOSQUITTO = "/usr/sbin/mosquitto"
PREFIX = "bench"


def walks(explorers: int, events: int) -> list[list[dict[str, Any]]]:
    grid = GridDomain.from_file(DEFAULT_MAP)
    out = []
    for k in range(explorers):
        rng = np.random.default_rng(k)
        s, walk = grid.start, []
        for a in rng.integers(0, 4, events).tolist():
            walk.append({"state": list(grid.cell(s)), "action": ACTIONS[a]})
            s = int(grid.next_state[s, a])
        out.append(walk)
    return out


async def through(port: int, explorers: int, events: int, batch: int, tag: str) -> float:
    """Decisions a second for ``explorers`` x ``events`` events sent ``batch`` per message,
    each explorer sending its next message once the decisions of the last one are back (as an
    explorer waits for advice before it moves: at most one message per explorer in flight)."""
    paths = walks(explorers, events)
    got = [0] * explorers
    arrived = [asyncio.Event() for _ in range(explorers)]
    async with (
        aiomqtt.Client("127.0.0.1", port, identifier=f"sub-{tag}") as sub,
        aiomqtt.Client("127.0.0.1", port, identifier=f"pub-{tag}") as pub,
    ):
        await sub.subscribe(f"{PREFIX}/default/+/decisions", qos=1)

        async def count() -> None:
            async for message in sub.messages:
                k = int(str(message.topic).split("/")[2].removeprefix(tag))
                got[k] += 1
                arrived[k].set()

        async def explorer(k: int) -> None:
            want = 1  # the session's start decision comes first
            for i in range(0, events, batch):
                chunk = paths[k][i : i + batch]
                body = json.dumps(chunk if batch > 1 else chunk[0])
                await pub.publish(f"{PREFIX}/default/{tag}{k}/events", body, qos=1)
                want += len(chunk)
                while got[k] < want:
                    arrived[k].clear()
                    await asyncio.wait_for(arrived[k].wait(), timeout=60)

        counter = asyncio.create_task(count())
        started = time.perf_counter()
        await asyncio.gather(*(explorer(k) for k in range(explorers)))
        took = time.perf_counter() - started
        counter.cancel()
    return sum(got) / took


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--explorers", type=int, default=10)
    ap.add_argument("--events", type=int, default=500, help="events per explorer")
    ap.add_argument("--batch", type=int, default=100, help="events per message, second run")
    ap.add_argument("--write", type=Path)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-mqtt-") as tmp:
        work = Path(tmp)
        port = free_port()
        conf = work / "mosquitto.conf"
        conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\n")
        broker = subprocess.Popen([MOSQUITTO, "-c", str(conf)], stderr=subprocess.DEVNULL)
        try:
            time.sleep(0.5)
            env = {"ADVISOR_MQTT_URL": f"mqtt://127.0.0.1:{port}", "ADVISOR_MQTT_PREFIX": PREFIX}
            with start_advisor(work, **env):
                time.sleep(1.0)  # the bridge connects
                one = asyncio.run(through(port, args.explorers, args.events, 1, "one"))
                many = asyncio.run(through(port, args.explorers, args.events, args.batch, "many"))
        finally:
            broker.terminate()
            broker.wait(10)
    version = subprocess.run([MOSQUITTO, "-h"], capture_output=True, text=True).stdout
    body = "\n".join([
        "## MQTT bridge",
        "",
        f"Command: `{command_line()}`  ",
        f"Machine: {machine()}; {version.splitlines()[0] if version else 'mosquitto'}.",
        "",
        f"{args.explorers} explorers x {args.events} events (random walks on the shipped maze), "
        "published at QoS 1 to the service's bridge through a Mosquitto broker on this machine; "
        "every decision comes back as one QoS 1 message (its start decision too); each explorer "
        "sends its next message once the decisions of its last one are back.",
        "",
        "| events per message | decisions/s through the broker |",
        "|---|---|",
        f"| 1 | {one:,.0f} |",
        f"| {args.batch} | {many:,.0f} |",
    ]) + "\n"  # fmt: skip
    print(body)
    if args.write:
        write_section(args.write, "bench_mqtt", body)


if __name__ == "__main__":
    main()
