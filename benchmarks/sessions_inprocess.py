"""What many live sessions cost the process beyond memory, measured in process (no server):
the objects the garbage collector tracks per session, the time of a full collection over
them, and the time of ``SessionRegistry.retable`` (run on the event loop at every ingest).

    .venv/bin/python benchmarks/sessions_inprocess.py [--sessions 100000]

Each session first gets one batch of 200 events, so that its history rings and advice log
exist, as in ``bench_service.py``'s memory figure.
"""

from __future__ import annotations

import asyncio
import gc
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.service import ops
from app.service.config import Settings
from app.service.schemas import SessionCreate
from app.service.state import open_state
from app.service.wire.events import read_moves
from benchmarks._report import arguments


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--sessions", type=int, default=100_000)
    args = ap.parse_args()
    n = args.sessions
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(data_dir=Path(tmp), viewer_enabled=False, max_sessions=n)
        state, _ = open_state(settings)
        domain = state.catalog.get("default")
        gc.collect()
        gc.freeze()  # as the service does once started: what is there now is not counted
        ops.warm_up()
        events = b"[" + b",".join([b'{"state":[28,0],"action":"E"}',
                                   b'{"state":[28,1],"action":"W"}'] * 100) + b"]"  # fmt: skip
        for _ in range(n):
            session, _ = asyncio.run(ops.open_session(state, domain, SessionCreate()))
            moves, _, _ = read_moves(domain.domain, events, len(events))
            state.registry.observe_batch(session, moves)
        tracked = len(gc.get_objects())
        full = []
        for _ in range(3):
            t0 = time.perf_counter()
            gc.collect()
            full.append((time.perf_counter() - t0) * 1e3)
        retable = []
        for _ in range(3):
            t0 = time.perf_counter()
            state.registry.retable(domain)
            retable.append((time.perf_counter() - t0) * 1e3)
        state.close()
    print(f"{n:,} sessions after {events.count(b'{')} events each: {tracked:,} tracked objects "
          f"({tracked / n:.1f} a session); full collection {sorted(full)[1]:.0f} ms; "
          f"retable {sorted(retable)[1]:.1f} ms (medians of 3)")  # fmt: skip


if __name__ == "__main__":
    main()
