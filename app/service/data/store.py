"""Durable state through SQLAlchemy 2: domains, expert trajectories and the prior's counts.

Tables (the same on every database; only the engine's connect options differ):

* ``domains``: name, map text, alpha0, created/updated times, and the data version: it goes up
  by one in the transaction of every change of the domain's prior (a put, an ingest), so a
  process that holds version v of a domain knows whether another has changed it since; a new
  domain's versions start at its creation time in milliseconds times 1,000 (:func:`first_version`),
  above any version of an earlier domain of the same name;
* ``trajectories``: domain, agent type, steps as a compact blob of little-endian int32
  (state, action) pairs, optional goal state, the data version that added it;
* ``prior_counts``: per (domain, table) the eqs. (1)-(2) increments as an int32 (states x
  actions) blob and the number of trajectories; table ``"*"`` is pooled over all agent types.
  4 actions, or 6 on a map of several floors: :func:`actions_of` reads it from the map's
  text, so a database of a version before floors is read as it was written (no migration).

A trajectory and the counts it adds are written in one transaction, so the counts always equal
a recount of the stored trajectories (:meth:`Store.recount`), whatever happens to the process.
Every method is synchronous and short; the service calls them from a worker thread.

On PostgreSQL every connection is made, and every exchange with the server (a statement, a
commit) answered, within ``timeout`` seconds (``ADVISOR_DATABASE_TIMEOUT``), else the
connection is closed and ``OperationalError`` raised (the service answers 503): a database that
stops answering holds a worker thread that long, not for ever. A commit whose answer did not
come is not known to have happened or not; nothing is acknowledged before it answered.
"""

from __future__ import annotations

import inspect as pyinspect
import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np
import numpy.typing as npt
from sqlalchemy import (
    BigInteger,
    DateTime,
    Float,
    ForeignKey,
    Integer,
    LargeBinary,
    String,
    Text,
    create_engine,
    delete,
    event,
    insert,
    inspect,
    select,
    text,
    update,
)
from sqlalchemy.engine import Connection, Engine
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

from app.advice.priors import ActionPrior, trajectory_counts
from app.arrays import IntArray
from app.domain.building import N_ACTIONS as BUILDING_ACTIONS
from app.domain.floors import is_floors_text
from app.domain.grid import N_ACTIONS as GRID_ACTIONS

POOLED = ActionPrior.POOLED
RETRIES = 5


class Base(DeclarativeBase):
    pass


class DomainRow(Base):
    __tablename__ = "domains"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True)
    map_text: Mapped[str] = mapped_column(Text)
    alpha0: Mapped[float] = mapped_column(Float)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    updated_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    version: Mapped[int] = mapped_column(BigInteger, default=0, server_default="0")


class TrajectoryRow(Base):
    __tablename__ = "trajectories"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    domain_id: Mapped[int] = mapped_column(ForeignKey("domains.id"), index=True)
    agent_type: Mapped[str | None] = mapped_column(String(64))
    n_steps: Mapped[int] = mapped_column(Integer)
    steps: Mapped[bytes] = mapped_column(LargeBinary)
    goal: Mapped[int | None] = mapped_column(Integer)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    version: Mapped[int] = mapped_column(BigInteger, default=0, server_default="0")


#: columns added after the first release: ``create_schema`` adds them to an older database
ADDED_COLUMNS = (("domains", "version"), ("trajectories", "version"))


class CountsRow(Base):
    __tablename__ = "prior_counts"
    domain_id: Mapped[int] = mapped_column(ForeignKey("domains.id"), primary_key=True)
    agent_type: Mapped[str] = mapped_column(String(64), primary_key=True)
    n_trajectories: Mapped[int] = mapped_column(Integer)
    counts: Mapped[bytes] = mapped_column(LargeBinary)


class LiveSessionRow(Base):
    """A live session written at a graceful shutdown, read back (and deleted) at the next
    start (:mod:`app.service.live.codec`)."""

    __tablename__ = "live_sessions"
    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    state: Mapped[bytes] = mapped_column(LargeBinary)
    saved_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))


class MetaRow(Base):
    __tablename__ = "service_meta"
    key: Mapped[str] = mapped_column(String(64), primary_key=True)
    value: Mapped[str] = mapped_column(Text)


@dataclass(frozen=True)
class DomainRecord:
    name: str
    map_text: str
    alpha0: float
    created_at: datetime
    updated_at: datetime
    version: int = 0  # the data version (see the module)


@dataclass(frozen=True)
class TableCounts:
    """One prior table: how many trajectories, and their eq. (1) increments (states x 4)."""

    n_trajectories: int
    counts: IntArray


@dataclass(frozen=True)
class Trajectory:
    """(state, action) pairs (T x 2) of one expert, its agent type and goal state if known."""

    agent_type: str | None
    pairs: IntArray
    goal: int | None = None
    version: int = 0  # the data version that stored it (0: not stored yet)


#: The largest stored count (and trajectory number): counts are int32, the column 4 bytes on
#: PostgreSQL. Past it, ingestion is refused whole (:class:`CountsFull`), never wrapped round.
COUNT_MAX = 2**31 - 1


class CountsFull(ValueError):
    """Adding these trajectories would take a stored count past :data:`COUNT_MAX`."""


def _check_fits(table: str, n_trajectories: int, counts: IntArray) -> None:
    if n_trajectories > COUNT_MAX or (counts.size and int(counts.max()) > COUNT_MAX):
        raise CountsFull(table)


def _pack(a: npt.ArrayLike) -> bytes:
    return np.ascontiguousarray(a, dtype="<i4").tobytes()


def _unpack(blob: bytes, width: int = 2) -> IntArray:
    return np.frombuffer(blob, dtype="<i4").reshape(-1, width).astype(np.int64)


def first_version(created: datetime) -> int:
    """A new domain's first data version: its creation time in milliseconds, times 1,000 (below
    2**53 until the year 2255, so that Redis' scripts compare versions exactly). A domain
    deleted and made again starts above every version of the one before as long as that one
    took fewer than 1,000 changes per millisecond of its life."""
    return int(created.timestamp() * 1000) * 1000


def _utc(t: datetime) -> datetime:
    return t if t.tzinfo is not None else t.replace(tzinfo=UTC)


def _record(row: Any) -> DomainRecord:
    return DomainRecord(
        row.name, row.map_text, row.alpha0, _utc(row.created_at), _utc(row.updated_at),
        row.version,
    )  # fmt: skip


def _rows(map_text: str) -> list[str]:
    """A stored map's rows, without the header lines of its frame and destinations (they hold
    ':'); on a map of several floors each floor's rows after a line that marks it, and its
    connections: what makes its states and moves."""
    if not is_floors_text(map_text):
        return [line for line in map_text.splitlines() if ":" not in line]
    return [
        "floor:" if line.startswith("floor:") else line
        for line in map_text.splitlines()
        if ":" not in line or line.startswith(("floor:", "connection:"))
    ]


def actions_of(map_text: str) -> int:
    """The actions of a stored map, the width of its counts: 6 on a map of several floors
    (N, E, S, W, U, D), else 4 (every map a version before floors stored)."""
    return BUILDING_ACTIONS if is_floors_text(map_text) else GRID_ACTIONS


def table_increments(
    items: Sequence[Trajectory], n_states: int, n_actions: int = GRID_ACTIONS
) -> dict[str, TableCounts]:
    """What ``items`` add to each table: every trajectory to ``"*"``, typed ones to their type
    (eq. (1) with delta = 0, as :class:`ActionPrior` counts them)."""
    groups: dict[str, list[IntArray]] = {POOLED: [t.pairs for t in items]}
    for t in items:
        if t.agent_type is not None:
            groups.setdefault(t.agent_type, []).append(t.pairs)
    return {
        key: TableCounts(
            len(trajs), trajectory_counts(trajs, n_states, n_actions=n_actions).astype(np.int64)
        )
        for key, trajs in groups.items()
    }


class Store:
    """The repository: every read and write of durable state goes through here."""

    def __init__(self, url: str, timeout: float = 10.0):
        connect_args = {"timeout": 30} if url.startswith("sqlite") else {}
        self.engine: Engine = create_engine(
            url, connect_args=connect_args, pool_pre_ping=True, pool_timeout=timeout
        )
        if self.engine.dialect.name == "sqlite":
            event.listen(self.engine, "connect", _sqlite_pragmas)
        elif self.engine.dialect.driver == "psycopg":
            _with_deadlines(self.engine, timeout)

    @property
    def dialect(self) -> str:
        return self.engine.dialect.name

    def create_schema(self) -> None:
        """The tables, and the columns of :data:`ADDED_COLUMNS` an older database lacks."""
        Base.metadata.create_all(self.engine)
        have = inspect(self.engine)
        for table, column in ADDED_COLUMNS:
            if column not in {c["name"] for c in have.get_columns(table)}:
                with self.engine.begin() as conn:
                    conn.execute(text(
                        f"ALTER TABLE {table} ADD COLUMN {column} BIGINT NOT NULL DEFAULT 0"
                    ))  # fmt: skip

    def close(self) -> None:
        self.engine.dispose()

    def ping(self) -> None:
        with self.engine.connect() as conn:
            conn.execute(text("SELECT 1"))

    # ---- meta ---------------------------------------------------------------------------------
    def get_meta(self, key: str) -> str | None:
        with self.engine.connect() as conn:
            return conn.execute(select(MetaRow.value).where(MetaRow.key == key)).scalar()

    def set_meta(self, key: str, value: str) -> None:
        with self.engine.begin() as conn:
            conn.execute(delete(MetaRow).where(MetaRow.key == key))
            conn.execute(insert(MetaRow).values(key=key, value=value))

    # ---- live sessions over a restart ---------------------------------------------------------
    def save_sessions(self, sessions: Sequence[tuple[str, bytes]]) -> None:
        """Write (id, state) of the live sessions, replacing any written before."""
        now = datetime.now(UTC)
        with self.engine.begin() as conn:
            conn.execute(delete(LiveSessionRow))
            if sessions:
                conn.execute(
                    insert(LiveSessionRow),
                    [{"id": sid, "state": raw, "saved_at": now} for sid, raw in sessions],
                )

    def take_sessions(self) -> list[bytes]:
        """The sessions written at the last shutdown, deleted as they are read (a crash later
        must not bring back sessions that went on elsewhere)."""
        with self.engine.begin() as conn:
            rows = conn.execute(select(LiveSessionRow.state)).scalars().all()
            conn.execute(delete(LiveSessionRow))
        return list(rows)

    # ---- domains ------------------------------------------------------------------------------
    def domains(self) -> list[DomainRecord]:
        with self.engine.connect() as conn:
            rows = conn.execute(select(DomainRow).order_by(DomainRow.name)).all()
        return [_record(r) for r in rows]

    def domain(self, name: str) -> DomainRecord | None:
        with self.engine.connect() as conn:
            row = conn.execute(select(DomainRow).where(DomainRow.name == name)).one_or_none()
        return None if row is None else _record(row)

    def versions(self) -> dict[str, int]:
        """Every domain's data version, by name."""
        with self.engine.connect() as conn:
            rows = conn.execute(select(DomainRow.name, DomainRow.version)).all()
        return {r.name: r.version for r in rows}

    def snapshot(
        self, name: str, since: int | None = None
    ) -> tuple[DomainRecord, dict[str, TableCounts], list[Trajectory]] | None:
        """(record, counts, the trajectories added after data version ``since``) of ``name``
        as of one data version (None: no such domain; ``since`` None: no trajectories). Read
        with the version before and after: a change between them reads again, so the counts
        are those of the record's version."""
        for _ in range(100):
            rec = self.domain(name)
            if rec is None:
                return None
            counts = self.counts(name)
            added = [] if since is None else self.trajectories(name, since)
            again = self.domain(name)
            if (
                again is not None
                and again.version == rec.version
                and again.map_text == rec.map_text
            ):
                return rec, counts, [t for t in added if t.version <= rec.version]
        raise RuntimeError(f"domain {name!r} kept changing while it was read")

    def put_domain(
        self, name: str, map_text: str, alpha0: float
    ) -> tuple[DomainRecord, bool, bool]:
        """Create or replace; returns (record, created, kept_data). A changed map deletes the
        old trajectories and counts (their states belong to the old map)."""
        now = datetime.now(UTC)
        with self.engine.begin() as conn:
            old = conn.execute(
                select(DomainRow).where(DomainRow.name == name).with_for_update()
            ).one_or_none()
            if old is None:
                conn.execute(
                    insert(DomainRow).values(
                        name=name, map_text=map_text, alpha0=alpha0, created_at=now,
                        updated_at=now, version=first_version(now),
                    )
                )  # fmt: skip
                return (
                    DomainRecord(name, map_text, alpha0, now, now, first_version(now)),
                    True,
                    False,
                )
            kept = _rows(old.map_text) == _rows(map_text)  # a new frame keeps the states
            if not kept:
                self._delete_data(conn, old.id)
            version = old.version + 1
            conn.execute(
                update(DomainRow)
                .where(DomainRow.id == old.id)
                .values(map_text=map_text, alpha0=alpha0, updated_at=now, version=version)
            )
            created = _utc(old.created_at)
            return DomainRecord(name, map_text, alpha0, created, now, version), False, kept

    def delete_domain(self, name: str) -> bool:
        with self.engine.begin() as conn:
            dom = self._domain_id(conn, name)
            if dom is None:
                return False
            self._delete_data(conn, dom)
            conn.execute(delete(DomainRow).where(DomainRow.id == dom))
        return True

    @staticmethod
    def _delete_data(conn: Connection, domain_id: int) -> None:
        conn.execute(delete(TrajectoryRow).where(TrajectoryRow.domain_id == domain_id))
        conn.execute(delete(CountsRow).where(CountsRow.domain_id == domain_id))

    @staticmethod
    def _domain_id(conn: Connection, name: str) -> int | None:
        return conn.execute(select(DomainRow.id).where(DomainRow.name == name)).scalar()

    # ---- trajectories and counts --------------------------------------------------------------
    def add_trajectories(
        self, name: str, items: Sequence[Trajectory], n_states: int, n_actions: int = GRID_ACTIONS
    ) -> int:
        """Store ``items`` and add their counts (``n_actions`` wide: the map's actions), in one
        transaction; returns the domain's data version that holds them. KeyError: no such
        domain.

        Two writers may both create a table's counts row; the loser's transaction is rolled
        back whole and retried, and then finds the row and adds to it."""
        increments = table_increments(items, n_states, n_actions)
        for attempt in range(RETRIES):
            try:
                return self._add_trajectories(name, items, n_states, increments)
            except IntegrityError:
                if attempt == RETRIES - 1:
                    raise
        raise AssertionError("unreachable")

    def _add_trajectories(
        self,
        name: str,
        items: Sequence[Trajectory],
        n_states: int,
        increments: dict[str, TableCounts],
    ) -> int:
        now = datetime.now(UTC)
        with self.engine.begin() as conn:
            dom = self._domain_id(conn, name)
            if dom is None:
                raise KeyError(name)
            # writes first: the transaction holds the write lock (on PostgreSQL the domain's
            # row) from here on, so versions are taken in the order of the commits
            conn.execute(
                update(DomainRow).where(DomainRow.id == dom).values(version=DomainRow.version + 1)
            )
            version = int(conn.execute(select(DomainRow.version).where(DomainRow.id == dom))
                          .scalar_one())  # fmt: skip
            conn.execute(
                insert(TrajectoryRow),
                [
                    {"domain_id": dom, "agent_type": t.agent_type, "n_steps": len(t.pairs),
                     "steps": _pack(t.pairs), "goal": t.goal, "created_at": now,
                     "version": version}
                    for t in items
                ],
            )  # fmt: skip
            for key, inc in increments.items():
                self._add_counts(conn, dom, key, inc, n_states)
        return version

    @staticmethod
    def _add_counts(conn: Connection, dom: int, key: str, inc: TableCounts, n_states: int) -> None:
        where = (CountsRow.domain_id == dom) & (CountsRow.agent_type == key)
        row = conn.execute(
            select(CountsRow.n_trajectories, CountsRow.counts).where(where).with_for_update()
        ).one_or_none()
        if row is None:
            _check_fits(key, inc.n_trajectories, inc.counts)
            values = {"domain_id": dom, "agent_type": key, "n_trajectories": inc.n_trajectories,
                      "counts": _pack(inc.counts)}  # fmt: skip
            conn.execute(insert(CountsRow).values(**values))
            return
        total = _unpack(row.counts, inc.counts.shape[1]) + inc.counts
        n = row.n_trajectories + inc.n_trajectories
        _check_fits(key, n, total)
        conn.execute(update(CountsRow).where(where).values(n_trajectories=n, counts=_pack(total)))

    def counts(self, name: str) -> dict[str, TableCounts]:
        """The stored counts of every table of a domain (empty if it has none)."""
        with self.engine.connect() as conn:
            dom = self._domain_id(conn, name)
            text = conn.execute(select(DomainRow.map_text).where(DomainRow.id == dom)).scalar()
            rows = conn.execute(
                select(CountsRow.agent_type, CountsRow.n_trajectories, CountsRow.counts).where(
                    CountsRow.domain_id == dom
                )
            ).all()
        width = actions_of(text or "")
        return {r.agent_type: TableCounts(r.n_trajectories, _unpack(r.counts, width)) for r in rows}

    def trajectories(self, name: str, since: int | None = None) -> list[Trajectory]:
        """The stored trajectories of ``name`` in the order they were stored (``since``: only
        those added after that data version)."""
        with self.engine.connect() as conn:
            dom = self._domain_id(conn, name)
            where = TrajectoryRow.domain_id == dom
            if since is not None:
                where = where & (TrajectoryRow.version > since)
            rows = conn.execute(
                select(
                    TrajectoryRow.agent_type, TrajectoryRow.steps, TrajectoryRow.goal,
                    TrajectoryRow.version,
                )
                .where(where)
                .order_by(TrajectoryRow.id)
            ).all()  # fmt: skip
        return [Trajectory(r.agent_type, _unpack(r.steps), r.goal, r.version) for r in rows]

    def recount(
        self, name: str, n_states: int, n_actions: int = GRID_ACTIONS
    ) -> dict[str, TableCounts]:
        """The counts recomputed from the stored trajectories (to check :meth:`counts`)."""
        items = self.trajectories(name)
        return table_increments(items, n_states, n_actions) if items else {}


def _with_deadlines(engine: Engine, deadline: float) -> None:
    """psycopg's connections of ``engine`` made within ``deadline`` seconds and each exchange
    answered within it (see the module); a psycopg without ``wait(..., timeout=)`` (older than
    the one this was written for) keeps only the connection's time limit."""
    import psycopg

    found = getattr(psycopg.errors, "_WaitTimeout", None)
    params = pyinspect.signature(psycopg.Connection.wait).parameters
    timed: type[psycopg.Connection[Any]] = psycopg.Connection
    if isinstance(found, type) and {"interval", "timeout"} <= set(params):
        expired: type[BaseException] = found

        class Timed(psycopg.Connection[Any]):
            def wait(self, gen: Any, interval: float = 0.1, timeout: float | None = None) -> Any:
                limit = deadline if timeout is None else min(timeout, deadline)
                try:
                    return super().wait(gen, interval, limit)
                except expired:
                    self.pgconn.finish()  # in the middle of an exchange: not usable again
                    raise psycopg.OperationalError(
                        f"the database did not answer within {deadline:g} s"
                    ) from None

        timed = Timed

    @event.listens_for(engine, "do_connect")
    def connect(_dialect: Any, _record: Any, cargs: Any, cparams: dict[str, Any]) -> Any:
        cparams.setdefault("connect_timeout", max(2, math.ceil(deadline)))
        return timed.connect(*cargs, **cparams)


def _sqlite_pragmas(dbapi_conn: Any, _record: Any) -> None:
    """WAL (readers never block the writer) and fsync at every commit (acknowledged = on disk)."""
    cur = dbapi_conn.cursor()
    for pragma in ("journal_mode=WAL", "synchronous=FULL", "foreign_keys=ON", "busy_timeout=30000"):
        cur.execute(f"PRAGMA {pragma}")
    cur.close()
