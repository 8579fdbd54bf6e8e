"""Service settings: one pydantic-settings class; every field can be set as ``ADVISOR_<NAME>``."""

from __future__ import annotations

import re
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Literal

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from app.service.clients import networks

REPO_ROOT = Path(__file__).resolve().parents[2]
try:
    VERSION = version("hidden-goal-advisor")
except PackageNotFoundError:  # running from a source tree that was not installed
    VERSION = "0+unknown"
MiB = 1024 * 1024
#: What a client of ADVISOR_CLIENT_KEYS may be called (it names a Redis key and a 429's detail).
CLIENT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


ORIGIN = re.compile(r"https?://(\[[0-9a-f:.]+\]|[a-z0-9.-]+)(:\d{1,5})?")


def page_origin(text: str) -> str:
    """An origin as a browser sends it (``Origin``): scheme, host and port, lower case, no
    path; ValueError for what is not one."""
    origin = text.strip().rstrip("/").lower()
    if not ORIGIN.fullmatch(origin):
        raise ValueError(
            f"{text!r} is not the origin of a page: scheme://host[:port], e.g. "
            "http://127.0.0.1:8080 (no path)"
        )
    return origin


#: guide's lead values are made for a served map of at most this many destinations x cells
#: by default (``ADVISOR_LEAD_CELLS``; ``GuideMap.lead``): about a second of preparation; a
#: 256 x 256 city map's (8 destinations) take 7 s, a 5-floor 128 x 128 hospital's (40) 37 s,
#: which its first guide session waits for (docs/PERFORMANCE.md, "guide's lead values")
SERVICE_LEAD_CELLS = 50_000


class Settings(BaseSettings):
    """How the advice service runs. Defaults suit one machine; override with ``ADVISOR_*``."""

    # errors never show the values given: some are secrets (keys)
    model_config = SettingsConfigDict(
        env_prefix="ADVISOR_", extra="ignore", hide_input_in_errors=True
    )

    host: str = Field("127.0.0.1", description="Interface to listen on.")
    port: int = Field(8000, ge=0, le=65535, description="HTTP port of the API.")
    data_dir: Path = Field(Path("data"), description="SQLite file and admin key live here.")
    database_url: str | None = Field(
        None, description="SQLAlchemy URL; default: SQLite file <data_dir>/advisor.db (WAL)."
    )
    admin_key: SecretStr | None = Field(
        None, description="X-API-Key for admin routes; generated and stored if not given."
    )
    operator_key: SecretStr | None = Field(
        None,
        description="Read-only X-API-Key for live positions and paths (/overview's sessions, "
        "GET /sessions, the viewer); generated and stored if not given.",
    )
    session_idle_seconds: float = Field(1800.0, gt=0, description="Idle sessions expire.")
    sweep_seconds: float = Field(15.0, gt=0, description="How often expired sessions go.")
    max_sessions: int = Field(20_000, ge=1, description="Live sessions at most (then 503).")
    max_body_bytes: int = Field(2 * MiB, ge=1024, description="Request/message size limit.")
    max_batch_events: int = Field(5_000, ge=1, description="Events per request or message.")
    max_trajectory_steps: int = Field(200_000, ge=1, description="Steps per ingest request.")
    max_window: int = Field(10_000, ge=1, description="Largest history window W a session may ask.")
    max_jump: int = Field(
        8, ge=1, le=64,
        description="Positions in metres: a reading this many moves or fewer from the last "
        "cell is walked along a shortest path; a farther one is refused (422).",
    )  # fmt: skip
    max_expert_pairs: int = Field(
        2_000_000, ge=1,
        description="Simulated experts of a PUT: at most this many (state, action) pairs.",
    )  # fmt: skip
    max_map_cells: int = Field(250_000, ge=4, description="Largest map (rows x cols).")
    recent_path: int = Field(100, ge=1, description="Cells of recent path kept per session.")
    recent_p_normal: int = Field(200, ge=1, description="p_normal values kept per session.")
    replay_steps: int = Field(
        500, ge=0, le=100_000,
        description="Decisions of its last steps each session keeps, so that a retried event "
        "(one with a step already applied) is answered again rather than applied twice; an "
        "older step is refused (409). 53 bytes a step, reserved for each session.",
    )  # fmt: skip
    viewer_enabled: bool = Field(
        True, description="serve starts the viser viewer, in a process of its own."
    )
    viewer_port: int = Field(8080, ge=0, le=65535, description="Port of the viser viewer.")
    viewer_host: str = Field(
        "127.0.0.1",
        description="Interface of the viewer: loopback unless set (it shows where explorers "
        "are and were, and asks no key of a browser).",
    )
    viewer_origins: list[str] = Field(
        default_factory=list,
        description="Origins of pages (scheme://host:port) a browser may open the viewer from "
        "beyond its own address's (loopback ones when it listens on loopback or 0.0.0.0), as "
        'JSON: e.g. ["http://127.0.0.1:9090"] when Docker publishes it on port 9090. '
        "Pages of any other origin are refused (403).",
    )
    static_dir: Path = Field(REPO_ROOT / "static", description="Pages served at / and /static.")
    bootstrap_experts: Literal["start", "anywhere"] = Field(
        "start", description="Where the simulated experts of the default domain start."
    )
    bootstrap_per_goal: int = Field(10, ge=1, description="Expert trajectories per goal.")
    bootstrap_seed: int = Field(0, description="Seed of the default domain's experts.")
    bootstrap_alpha0: float = Field(1.0, gt=0, description="alpha0 of the default domain.")
    # ---- several workers: sessions in Redis (docs/SCALING.md) ----
    workers: int = Field(
        1, ge=1, le=64,
        description="Worker processes serving the API (one per core); more than 1 needs "
        "ADVISOR_REDIS_URL.",
    )  # fmt: skip
    redis_url: str | None = Field(
        None,
        description="Redis, e.g. redis://127.0.0.1:6379/0: live sessions are kept there, every "
        "event acknowledged once its session's new state is in Redis, so any worker answers "
        "any session and a worker's death loses none.",
    )
    redis_prefix: str = Field(
        "advisor", pattern=r"^[A-Za-z0-9_.-]{1,64}$", description="First part of its keys."
    )
    redis_timeout: float = Field(
        1.0, gt=0, le=60,
        description="Seconds a command to Redis (or a connection to it) may take; then, and at "
        "once while Redis is known to be down, requests that need it are answered 503 with "
        "Retry-After (Redis is tried again every second).",
    )  # fmt: skip
    database_timeout: float = Field(
        10.0, gt=0, le=600,
        description="PostgreSQL: seconds a connection, or one exchange with the database, may "
        "take before the request is answered 503 with Retry-After (SQLite waits up to 30 s "
        "for a lock).",
    )  # fmt: skip
    # ---- operations: metrics, logs, the MQTT bridge ----
    metrics_enabled: bool = Field(True, description="Count requests; serve GET /metrics.")
    log_format: Literal["text", "json"] = Field(
        "text", description="Log lines as text, or as JSON objects with a request id."
    )
    access_log_events: bool = Field(
        False, description="Also write an access-log line per event request and websocket."
    )
    mqtt_url: str | None = Field(
        None, description="MQTT broker, e.g. mqtt://127.0.0.1:1883: starts the bridge."
    )
    mqtt_prefix: str = Field(
        "advisor", pattern=r"^[A-Za-z0-9_.-]{1,64}$", description="First level of its topics."
    )
    mqtt_max_explorers: int = Field(
        10_000, ge=1, description="Explorers the bridge keeps a session for (then the oldest go)."
    )
    mqtt_queue: int = Field(
        1000, ge=1, description="MQTT messages waiting to be handled or published, at most."
    )

    # ---- what one client, or all of them, may take (docs/RELIABILITY.md) -----------------
    max_session_memory: int = Field(
        1024 * MiB, ge=MiB,
        description="Bytes the live sessions may reserve in all: each reserves the most its "
        "state can take (its window, its goals); beyond it new sessions get 503.",
    )  # fmt: skip
    client_max_sessions: int = Field(
        1000, ge=1,
        description="Live sessions one client may hold (then 429). A client is the key it "
        "sends, if the service knows it (the operator key, ADVISOR_CLIENT_KEYS), else its "
        "address; the admin key's sessions count against no client. Over MQTT, a client is "
        "the device its topic names ('mqtt <device>').",
    )  # fmt: skip
    client_max_session_memory: int = Field(
        256 * MiB, ge=MiB, description="Session memory one client may reserve (then 429)."
    )
    client_keys: dict[str, SecretStr] = Field(
        default_factory=dict,
        description="Keys (X-API-Key) that make a client of their own for the quotas, as JSON "
        '{"name": "key"}: e.g. the positioning gateway of a building, whose explorers would '
        "otherwise share its address's quota. Sessions made with one count against its name "
        "(never the key); they give no other right. Keys of at least 16 characters.",
    )
    trusted_proxies: list[str] = Field(
        default_factory=list,
        description="Addresses or networks (CIDR) of proxies in front of the service: for a "
        "request from one of them, the client is the last address of X-Forwarded-For that is "
        "not a trusted proxy. Empty: the peer's address is the client.",
    )
    max_goal_cells: int = Field(
        2_097_152, ge=1,
        description="goal_aware and guide keep per-goal tables of goals x cells: maps of more "
        "are refused (PUT: 422).",
    )  # fmt: skip
    max_domain_memory: int = Field(
        256 * MiB, ge=MiB,
        description="Bytes what the strategies need of one domain may keep: its goal priors "
        "(64 bytes a goal and free cell) and guide map (16), built when the domain is PUT. A "
        "map that would need more is refused (PUT: 422).",
    )  # fmt: skip
    lead_cells: int = Field(
        SERVICE_LEAD_CELLS, ge=0,
        description="guide's lead values (where a piece saves a walker that keeps a heading "
        "more than its price; 16 bytes a goal and free cell) are made when a map is PUT if "
        "it has at most this many goals x free cells (never beyond 2.5 million), seconds of "
        "one core for each 100,000 (docs/PERFORMANCE.md); a larger map's walkers that keep a "
        "heading are led where their next move loses ground.",
    )  # fmt: skip
    max_goal_window: int = Field(
        1_048_576, ge=1,
        description="A goal_aware session with beta > 0 keeps a per-goal window of goals x "
        "window values: more is refused (422).",
    )  # fmt: skip

    overview_seconds: float = Field(
        1.0, ge=0, description="GET /overview is made at most once per this many seconds."
    )
    path_retention_seconds: float = Field(
        600.0, gt=0,
        description="Seconds the cells an explorer was at (its recent path, where it was "
        "advised) are kept; its current cell stays while its session lives.",
    )  # fmt: skip
    max_header_bytes: int = Field(
        16 * 1024, ge=1024, description="Request headers at most this many bytes (then 431)."
    )
    header_timeout: float = Field(
        10.0, gt=0, description="Seconds a request's headers may take to arrive (then 408)."
    )
    body_timeout: float = Field(
        30.0, gt=0, description="Seconds a request's body may take after its headers (408)."
    )
    max_connections: int = Field(
        1000, ge=1,
        description="Open connections at most, websockets included (then 503 and closed); "
        "lowered to the process's file descriptor limit less 64 if that is lower.",
    )  # fmt: skip
    client_max_connections: int = Field(
        256, ge=1,
        description="Open connections one client (the peer's address) may hold, websockets "
        "included (then 429 and closed); proxies in ADVISOR_TRUSTED_PROXIES are not capped.",
    )  # fmt: skip

    @model_validator(mode="after")
    def _workers_share(self) -> Settings:
        if self.workers > 1 and not self.redis_url:
            raise ValueError(
                f"workers {self.workers} needs ADVISOR_REDIS_URL: workers share their live "
                "sessions through Redis (one worker runs without it)"
            )
        return self

    @field_validator("client_keys")
    @classmethod
    def _client_keys(cls, keys: dict[str, SecretStr]) -> dict[str, SecretStr]:
        seen: set[str] = set()
        for name, key in keys.items():
            if not CLIENT_NAME.fullmatch(name):
                raise ValueError(
                    f"client name {name!r}: letters, digits, '_', '.', '-', at most 64"
                )
            secret = key.get_secret_value()
            if len(secret) < 16:  # the key is never named: a message may be logged
                raise ValueError(f"the key of client {name!r} is shorter than 16 characters")
            if secret in seen:
                raise ValueError(f"the key of client {name!r} is another client's too")
            seen.add(secret)
        return keys

    @field_validator("viewer_origins")
    @classmethod
    def _origins(cls, entries: list[str]) -> list[str]:
        return [page_origin(e) for e in entries]

    @field_validator("trusted_proxies")
    @classmethod
    def _networks(cls, entries: list[str]) -> list[str]:
        networks(entries)  # ValueError names an entry that is no address or network
        return entries

    @property
    def db_url(self) -> str:
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'advisor.db').resolve()}"
