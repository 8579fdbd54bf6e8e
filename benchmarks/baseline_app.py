"""The framework's own limit: bare FastAPI endpoints on the service's routes, run by uvicorn
exactly as ``python -m app serve`` runs the service (one worker, the same websocket options,
from :func:`app.cli.serve.uvicorn_options`).

* ``POST /sessions/{session_id}/events``: reads the body, parses it as JSON and answers a fixed
  JSON text of ``BASELINE_ANSWER_BYTES`` bytes (the size of the service's answer to the same
  body): what any endpoint taking those events and giving those answers must pay at least.
* ``WS /sessions/{session_id}/stream``: accepts and echoes every text frame.
* ``WS /sessions/{session_id}/answer``: answers every text frame with a fixed text of
  ``--frame-answer-bytes`` bytes (the size of the service's answer to such a frame): the
  framework's cost of the same traffic in both directions, without any work.

    python benchmarks/baseline_app.py --port 8001 [--answer-bytes 180]
        [--frame-answer-bytes 144000] [--log-level warning]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import uvicorn
from fastapi import FastAPI, Request, Response, WebSocket, WebSocketDisconnect

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.cli.serve import uvicorn_options
from app.service.config import Settings
from benchmarks._report import arguments


def answer_of(size: int) -> bytes:
    """A JSON object of exactly ``size`` bytes (at least 12)."""
    head = b'{"pad":"'
    return head + b"x" * max(0, size - len(head) - 2) + b'"}'


def create_baseline(answer_bytes: int, frame_answer_bytes: int = 0) -> FastAPI:
    app = FastAPI(title="baseline")
    answer = answer_of(answer_bytes)
    frame_answer = answer_of(frame_answer_bytes).decode()

    @app.post("/sessions/{session_id}/events")
    async def events(session_id: str, request: Request) -> Response:
        json.loads(await request.body())
        return Response(answer, media_type="application/json")

    @app.websocket("/sessions/{session_id}/stream")
    async def stream(websocket: WebSocket, session_id: str) -> None:
        await websocket.accept()
        try:
            while True:
                await websocket.send_text(await websocket.receive_text())
        except WebSocketDisconnect:
            return

    @app.websocket("/sessions/{session_id}/answer")
    async def answer_frames(websocket: WebSocket, session_id: str) -> None:
        await websocket.accept()
        try:
            while True:
                await websocket.receive_text()
                await websocket.send_text(frame_answer)
        except WebSocketDisconnect:
            return

    return app


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--answer-bytes", type=int, default=180)
    ap.add_argument("--frame-answer-bytes", type=int, default=0)
    ap.add_argument("--log-level", default="warning")
    args = ap.parse_args()
    settings = Settings(port=args.port, viewer_enabled=False)
    uvicorn.run(
        create_baseline(args.answer_bytes, args.frame_answer_bytes),
        **uvicorn_options(settings, args.log_level),
    )


if __name__ == "__main__":
    main()
