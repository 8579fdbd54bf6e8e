"""Live sessions kept in Redis, so that any worker answers any session and a worker's death
loses nothing it acknowledged.

Each session is a Redis hash: its state as :func:`app.service.live.codec.dump` writes it
(window values, sums, counters, recent path, advice log), its step, its domain, its client and
what it reserves. An event is applied by a worker to its copy of the session (read from Redis
unless it holds a current one) and acknowledged only once the new state is in Redis: one
script (:data:`SCRIPT`, ``commit``) writes it if the step in Redis is still the one the
worker started from and the domain's prior has not changed since; otherwise it answers with
what Redis holds, and the worker reads it, catches up with the prior from the database, and
applies the event again. So decisions are those of one process, bit for bit, whichever
workers the events reach, and a prior update acknowledged by one worker is used by every
worker from the next event on.

The limits are global: the same script admits a new session against the live count, the
memory all sessions reserve, and the client's quota (one hash per client); the live sessions
are a sorted set by last activity, and the idle ones expire through it (any worker's sweep).
The decisions of each request are kept (their records appended to a string per session;
when it alone holds ``replay_steps`` steps it becomes the older one, replacing the one
before: the two hold at least the last ``replay_steps`` steps, and fewer than twice as many
plus one request's) so that a retry is answered again, from any worker. States and records
go to Redis packed (LZ4: :func:`app.service.live.codec.packed`), about a tenth of the bytes.

Where an explorer was is written without the cells older than the retention
(``ADVISOR_PATH_RETENTION_SECONDS``); a session that stays still keeps them in Redis until its
next event or its expiry, and every read (a worker's copy made from Redis) drops them.

Redis failing (:mod:`app.service.live.faults`): every call has a time limit
(``ADVISOR_REDIS_TIMEOUT``: the lanes' watchdog, redis-py's socket timeouts), every failure is
one exception (:class:`~app.service.live.faults.RedisDown`: 503), and while Redis is known to
be down calls are refused at once and a probe asks it again every second. An event is
acknowledged only once the commit script has answered ``ok``: what a worker answered 2xx is in
Redis. When Redis comes back without its data (restarted empty: its generation key ``P:gen``
is not the one the worker knew), the sessions the worker held that Redis no longer has are
marked lost (``P:lost``, for as long as their keys would have lived): their requests answer
410 saying so, from any worker; and the worker tells Redis its data versions again.

Keys (``P`` the prefix, ``ADVISOR_REDIS_PREFIX``): ``P:s:<id>`` the session, ``P:r:<id>`` and
``P:r:<id>:old`` its kept decisions, ``P:live`` (sorted set), ``P:mem``, ``P:c:<client>``,
``P:dom:<domain>`` (set), ``P:sum`` (hash: figures per session for the aggregates),
``P:v:<domain>`` (the data version of its prior, from the database), ``P:catalog`` (goes up
when a domain is made or deleted), ``P:gen`` (set once, by the first worker to start on this
Redis's data), ``P:lost`` (set: sessions lost with Redis' data).
The script reaches keys it derives from its arguments: this is for one Redis server (or
Sentinel), not Redis Cluster as it stands (docs/SCALING.md).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from typing import Any, cast

import hiredis
import numpy as np
import redis.asyncio as aioredis
import redis.exceptions as rx
from redis.asyncio.client import Pipeline
from redis.asyncio.retry import Retry
from redis.backoff import NoBackoff
from starlette.concurrency import run_in_threadpool

from app import strategies
from app.advice.advisor import Decision, DecisionBatch
from app.arrays import Moves
from app.service.data.domains import DomainCatalog, DomainNotFound, DomainState
from app.service.data.store import POOLED, Store
from app.service.live import codec
from app.service.live.faults import Breaker, RedisDown, SessionLost
from app.service.live.lanes import Lane
from app.service.live.registry import (
    Aggregate,
    ClientQuotaReached,
    LiveSession,
    SessionMemoryFull,
    SessionNotFound,
    SessionRegistry,
    SessionSettings,
    SessionSnapshot,
    SessionUnreadable,
    TooManySessions,
    joined,
)
from app.service.live.replay import part, retried

log = logging.getLogger("advisor.shared")

#: attempts at applying one request before giving up (each failed one means another worker
#: applied an event of the same session, or the prior changed, in between)
ATTEMPTS = 50
#: sessions that one sweep expires at most (the rest at the next)
SWEEP_BATCH = 1000
#: connections to Redis a worker keeps for the events' scripts: a session's always goes
#: through the same one (by its id), so its commands keep their order
LANES = 4

SCRIPT = r"""
local p, cmd = ARGV[1], ARGV[2]
local function skey(id) return p .. ':s:' .. id end
local function rkey(id) return p .. ':r:' .. id end
-- versions are integers below 2**53: compared as numbers, returned as the text Redis holds
local function version(domain) return redis.call('GET', p .. ':v:' .. domain) or '0' end
-- a session Redis does not hold: lost with Redis' data (marked by a worker that held it),
-- else gone (with the generation of Redis' data, for the worker to compare)
local function absent(id)
  if redis.call('SISMEMBER', p .. ':lost', id) == 1 then return {'lost'} end
  return {'gone', redis.call('GET', p .. ':gen') or ''}
end
local function drop(id)
  local k = skey(id)
  local h = redis.call('HMGET', k, 'domain', 'client', 'reserved')
  redis.call('ZREM', p .. ':live', id)
  redis.call('HDEL', p .. ':sum', id)
  if not h[1] then return 0 end
  redis.call('DEL', k, rkey(id), rkey(id) .. ':old')
  redis.call('SREM', p .. ':dom:' .. h[1], id)
  local r = tonumber(h[3]) or 0
  redis.call('DECRBY', p .. ':mem', r)
  if h[2] and h[2] ~= '' then
    local c = p .. ':c:' .. h[2]
    local n = redis.call('HINCRBY', c, 'n', -1)
    redis.call('HINCRBY', c, 'mem', -r)
    if n <= 0 then redis.call('DEL', c) end
  end
  return 1
end
local function expire(now, idle, most)
  local gone = redis.call('ZRANGEBYSCORE', p .. ':live', '-inf', now - idle, 'LIMIT', 0, most)
  for _, id in ipairs(gone) do drop(id) end
  return gone
end
local function refusal(reserved, client, limits)
  if redis.call('ZCARD', p .. ':live') >= limits[1] then return 'sessions' end
  local mem = tonumber(redis.call('GET', p .. ':mem') or '0')
  if mem + reserved > limits[2] then return 'memory' end
  if client ~= '' then
    local c = redis.call('HMGET', p .. ':c:' .. client, 'n', 'mem')
    if (tonumber(c[1]) or 0) >= limits[3] then return 'client_sessions' end
    if (tonumber(c[2]) or 0) + reserved > limits[4] then return 'client_memory' end
  end
  return nil
end

if cmd == 'create' then
  local id, blob, domain, client = ARGV[3], ARGV[4], ARGV[5], ARGV[6]
  local reserved, now, idle = tonumber(ARGV[7]), tonumber(ARGV[8]), tonumber(ARGV[9])
  local limits = {tonumber(ARGV[10]), tonumber(ARGV[11]), tonumber(ARGV[12]), tonumber(ARGV[13])}
  local summary, used, ttl = ARGV[14], tonumber(ARGV[15]), tonumber(ARGV[16])
  local v = version(domain)
  if tonumber(v) > used then return {'stale', v} end
  if refusal(reserved, client, limits) then expire(now, idle, 1000) end
  local why = refusal(reserved, client, limits)
  if why then return {why} end
  local k = skey(id)
  redis.call('HSET', k, 'blob', blob, 'step', '0', 'domain', domain, 'client', client,
             'reserved', ARGV[7], 'kept', '0', 'touched', ARGV[8])
  redis.call('PEXPIRE', k, ttl)
  redis.call('ZADD', p .. ':live', now, id)
  redis.call('INCRBY', p .. ':mem', reserved)
  if client ~= '' then
    redis.call('HINCRBY', p .. ':c:' .. client, 'n', 1)
    redis.call('HINCRBY', p .. ':c:' .. client, 'mem', reserved)
  end
  redis.call('SADD', p .. ':dom:' .. domain, id)
  redis.call('HSET', p .. ':sum', id, summary)
  return {'ok'}
elseif cmd == 'load' then
  local h = redis.call('HMGET', skey(ARGV[3]), 'blob', 'step', 'domain')
  if not h[1] then return absent(ARGV[3]) end
  return {'ok', h[1], h[2], version(h[3])}
elseif cmd == 'commit' then
  local id, expected, step, blob = ARGV[3], ARGV[4], ARGV[5], ARGV[6]
  local record, n, used = ARGV[7], tonumber(ARGV[8]), tonumber(ARGV[9])
  local now, keep = tonumber(ARGV[10]), tonumber(ARGV[11])
  local summary, ttl = ARGV[12], tonumber(ARGV[13])
  local k = skey(id)
  local h = redis.call('HMGET', k, 'step', 'domain', 'kept', 'touched')
  if not h[1] then return absent(id) end
  local v = version(h[2])
  if h[1] ~= expected then return {'moved', redis.call('HGET', k, 'blob'), h[1], v} end
  if tonumber(v) > used then return {'stale', redis.call('HGET', k, 'blob'), h[1], v} end
  local r = rkey(id)
  -- the keys' time to live is renewed once a quarter of it has gone by, not at every event:
  -- each key then outlives the session's last event by at least three quarters of ``ttl``
  -- (which is twice the idle timeout and a minute: the sweep drops an idle session first)
  local touched = tonumber(h[4]) or 0
  local renew = now - touched >= ttl / 4
  local kept = tonumber(h[3]) or 0
  if n > 0 and keep > 0 then
    -- the records go into two strings, appended to (a list's RPUSH of a batch's record costs
    -- Redis several times more): when the newer alone holds ``keep`` steps it becomes the
    -- older one, and the older one goes; together they always hold the last ``keep`` steps
    if redis.call('APPEND', r, record) == #record then
      redis.call('PEXPIRE', r, ttl)  -- a new string: it lives as long as the others
    end
    kept = kept + n
    if kept >= keep then
      -- renamed when written in one piece (its time to live goes with it), else copied: the
      -- copy keeps none of the room APPEND made for growing (up to as much again)
      if kept == n then
        redis.call('RENAME', r, r .. ':old')
      else
        redis.call('SET', r .. ':old', redis.call('GET', r), 'PX', ttl)
        redis.call('DEL', r)
      end
      kept = 0
    end
  end
  redis.call('HSET', k, 'blob', blob, 'step', step, 'kept', kept)
  if renew then
    redis.call('HSET', k, 'touched', now)
    redis.call('PEXPIRE', k, ttl)
    redis.call('PEXPIRE', r, ttl)
    redis.call('PEXPIRE', r .. ':old', ttl)
  end
  redis.call('ZADD', p .. ':live', now, id)
  redis.call('HSET', p .. ':sum', id, summary)
  return {'ok'}
elseif cmd == 'end' then
  return drop(ARGV[3])
elseif cmd == 'end_domain' then
  local ids = redis.call('SMEMBERS', p .. ':dom:' .. ARGV[3])
  for _, id in ipairs(ids) do drop(id) end
  redis.call('DEL', p .. ':dom:' .. ARGV[3])
  return #ids
elseif cmd == 'expire' then
  return expire(tonumber(ARGV[3]), tonumber(ARGV[4]), tonumber(ARGV[5]))
elseif cmd == 'lost' then
  -- Redis lost its data: of the sessions a worker held, those it no longer has are lost
  local ttl, gen, lost = tonumber(ARGV[3]), ARGV[4], {}
  for i = 5, #ARGV do
    if redis.call('EXISTS', skey(ARGV[i])) == 0 then
      redis.call('SADD', p .. ':lost', ARGV[i])
      lost[#lost + 1] = ARGV[i]
    end
  end
  if #lost > 0 then redis.call('PEXPIRE', p .. ':lost', ttl) end
  if gen ~= '' then redis.call('SET', p .. ':gen', gen, 'NX') end
  return {redis.call('GET', p .. ':gen') or '', lost}
elseif cmd == 'version' then
  local key = p .. ':v:' .. ARGV[3]
  if tonumber(ARGV[4]) > tonumber(redis.call('GET', key) or '0') then
    redis.call('SET', key, ARGV[4])
  end
  return 1
end
return redis.error_reply('unknown command ' .. cmd)
"""


def _summary(s: LiveSession) -> str:
    """What the aggregates read of a session: domain, steps, decisions, advice, P(M1 | H)."""
    a = s.advisor
    return f"{s.domain.name}|{a.steps}|{a.decisions}|{a.advice_count}|{s.p_normal!r}"


class _Redis(aioredis.Redis):
    """redis-py's client whose every command asks the breaker first (refused at once while
    Redis is known to be down) and whose failures are :class:`RedisDown`."""

    breaker: Breaker

    async def execute_command(self, *args: Any, **options: Any) -> Any:
        self.breaker.check()
        try:
            return await super().execute_command(*args, **options)  # type: ignore[no-untyped-call]
        except Exception as exc:
            down = self.breaker.failed(exc)
            if down is None:
                raise
            raise down from None

    async def unguarded(self, *args: Any) -> Any:
        """A command past the breaker (its probe, the start)."""
        return await super().execute_command(*args)  # type: ignore[no-untyped-call]

    def pipeline(self, transaction: bool = True, shard_hint: str | None = None) -> Pipeline:
        pipe = _Pipeline(self.connection_pool, self.response_callbacks, transaction, shard_hint)
        pipe.breaker = self.breaker
        return pipe


class _Pipeline(Pipeline):
    breaker: Breaker

    async def execute(self, raise_on_error: bool = True) -> list[Any]:
        self.breaker.check()
        try:
            return await super().execute(raise_on_error)
        except Exception as exc:
            down = self.breaker.failed(exc)
            if down is None:
                raise
            raise down from None


class SharedSessions:
    """Live sessions in Redis, this worker's registry a cache of the ones it used lately (see
    the module; a :class:`~app.service.live.sessions.Sessions`). ``timeout``: seconds a call
    to Redis may take (``ADVISOR_REDIS_TIMEOUT``)."""

    shared = True

    def __init__(
        self, registry: SessionRegistry, catalog: DomainCatalog, url: str, prefix: str,
        replay_steps: int, limits: tuple[int, int, int, int], timeout: float = 1.0,
    ):  # fmt: skip
        self.registry = registry
        self.catalog = catalog
        self.timeout = timeout
        # reads and rare writes: a pool, each command within the timeout; a connection lost
        # between commands (Redis closed it) is tried again once, at once, a timeout never
        self.redis = cast(_Redis, _Redis.from_url(
            url, socket_timeout=timeout, socket_connect_timeout=timeout,
            retry=Retry(NoBackoff(), 1, (rx.ConnectionError,)),
        ))  # fmt: skip
        self.breaker = Breaker(self._probe, self._back)
        self.redis.breaker = self.breaker
        # the scripts of events: a few single connections, which cost about half of a
        # pool's CPU a call (measured: docs/PERFORMANCE.md, "Workers")
        self._lanes = [Lane(url, timeout) for _ in range(LANES)]
        self._sha = ""
        self.prefix = prefix
        self.replay_steps = replay_steps
        self.limits = limits  # sessions, memory, per client: sessions, memory
        self._locks: dict[str, asyncio.Lock] = {}
        self._refreshing: dict[str, asyncio.Future[DomainState | None]] = {}
        self._catalog_epoch: int | None = None
        self._gen = ""  # the generation of Redis' data this worker knows (P:gen)
        self._losing: asyncio.Future[set[str]] | None = None
        self._owed = False  # a domain's change Redis was not told of (it was down)

    @property
    def max_sessions(self) -> int:
        return self.limits[0]

    async def _run(self, cmd: str, *args: Any, lane: str = "") -> Any:
        """The script's command ``cmd``: through the lane of session ``lane`` (the events'
        path: :mod:`app.service.live.lanes`), else redis-py's pool. RedisDown at once while
        Redis is known to be down, or when it fails now."""
        self.breaker.check()
        call = ("EVALSHA", self._sha, 0, self.prefix, cmd, *args)
        try:
            if lane:
                return await self._lanes[hash(lane) % LANES].call(*call)
            return await self.redis.execute_command(*call)
        except (aioredis.ResponseError, hiredis.ReplyError) as exc:
            if not (isinstance(exc, rx.NoScriptError) or str(exc).startswith("NOSCRIPT")):
                down = self.breaker.failed(exc)
                if down is None:
                    raise
                raise down from None
            self._sha = await self.redis.script_load(SCRIPT)  # Redis restarted, or flushed
            return await self._run(cmd, *args, lane=lane)
        except RedisDown:
            raise
        except Exception as exc:
            down = self.breaker.failed(exc)
            if down is None:
                raise
            raise down from None

    def _ttl(self) -> int:
        """Milliseconds a session's keys live without activity: past the idle timeout (the
        sweep drops idle sessions first; this bounds what a sweep never reached keeps)."""
        return int(self.registry.idle_seconds * 2000) + 60_000

    async def start(self) -> None:
        """Reach Redis (an error that says so if it does not answer), and tell it the data
        versions this worker read from the database at start (a worker that died between a
        commit and telling Redis left it behind)."""
        try:
            await self.redis.unguarded("PING")
            self._sha = await self.redis.unguarded("SCRIPT", "LOAD", SCRIPT)
            if isinstance(self._sha, bytes):
                self._sha = self._sha.decode()
            gen = f"{self.prefix}:gen"
            await self.redis.unguarded("SET", gen, secrets.token_hex(8), "NX")
            self._gen = (await self.redis.unguarded("GET", gen) or b"").decode()
        except (rx.ConnectionError, rx.TimeoutError, rx.ResponseError, OSError) as exc:
            raise RuntimeError(f"ADVISOR_REDIS_URL: Redis does not answer ({exc})") from None
        for d in self.catalog.states():
            await self._run("version", d.name, d.version)
        self._catalog_epoch = int(await self.redis.get(f"{self.prefix}:catalog") or 0)

    async def _probe(self) -> bytes | None:
        """The breaker's probe: Redis' generation key (a command Redis refuses while it is
        still loading its data, unlike PING)."""
        answer: bytes | None = await self.redis.unguarded("GET", f"{self.prefix}:gen")
        return answer

    async def _back(self, gen: bytes | None) -> None:
        """Redis answers again: if without its data, the sessions held here are lost; either
        way, it hears this worker's data versions again if a change was not told."""
        if (gen or b"").decode() != self._gen:
            await self._data_lost()
        elif self._owed:
            await self._tell_versions()

    async def _tell_versions(self) -> None:
        self._owed = False
        try:
            for d in self.catalog.states():
                await self._run("version", d.name, d.version)
            await self.redis.incr(f"{self.prefix}:catalog")  # every worker checks its list
        except RedisDown:
            self._owed = True
            raise

    async def _data_lost(self) -> set[str]:
        """Redis lost its data (its generation is not the one this worker knew): the sessions
        this worker held that Redis no longer has are marked lost (once for all who ask
        meanwhile); which they are."""
        running = self._losing
        if running is None:
            running = self._losing = asyncio.ensure_future(self._mark_lost())
            running.add_done_callback(lambda _: setattr(self, "_losing", None))
        return await asyncio.shield(running)

    async def _mark_lost(self) -> set[str]:
        ids = [s.id for s in self.registry.sessions()]
        fresh = secrets.token_hex(8)
        lost: set[str] = set()
        gen = b""
        for i in range(0, max(len(ids), 1), 1000):
            gen, marked = await self._run("lost", self._ttl(), fresh, *ids[i : i + 1000])
            lost.update(m.decode() for m in marked)
        self._gen = gen.decode()
        for sid in lost:
            self.registry.forget(sid)
        log.log(
            logging.WARNING if lost else logging.INFO,
            "Redis came back without its data: %d live sessions this worker held are lost "
            "(their requests answer 410)", len(lost),
        )  # fmt: skip
        self._owed = True
        await self._tell_versions()
        return lost

    async def _absent(self, session_id: str, got: list[Any]) -> SessionNotFound:
        """What to raise for a session Redis does not hold (the script's ``gone`` or
        ``lost``): lost with Redis' data (410), or not found (404)."""
        lost = got[0] == b"lost"
        if not lost and len(got) > 1 and got[1].decode() != self._gen:
            lost = session_id in await self._data_lost()
        self.registry.forget(session_id)
        return SessionLost(session_id) if lost else SessionNotFound(session_id)

    async def ready(self) -> str | None:
        """Whether Redis answers now (a PING within the timeout; at once while it is known to
        be down): None, or why not."""
        try:
            await self.redis.ping()  # type: ignore[misc]
        except RedisDown as exc:
            return exc.why
        return None

    async def domain(self, name: str) -> DomainState:
        return await self.fresh_domain(name)

    async def sync_domain(self, name: str) -> None:
        with contextlib.suppress(DomainNotFound):
            await self.fresh_domain(name)

    # ---- domains: what the database holds now --------------------------------------------
    async def fresh_domain(self, name: str) -> DomainState:
        """The domain ``name`` at the data version Redis says is current (read again from the
        database if this worker holds an older one); DomainNotFound if it is gone."""
        raw = await self.redis.get(f"{self.prefix}:v:{name}")
        local = self.catalog.find(name)
        if raw is None and local is None:
            state = await self._refresh(name)  # made elsewhere before any version was set?
        elif local is None or raw is None or int(raw) > local.version:
            state = await self._refresh(name)
        else:
            state = local
        if state is None:
            raise DomainNotFound(name)
        return state

    async def _at_version(self, name: str, version: int) -> DomainState:
        """The domain at data ``version`` or later."""
        local = self.catalog.find(name)
        if local is not None and local.version >= version:
            return local
        state = await self._refresh(name)
        if state is None:
            raise DomainNotFound(name)
        return state

    async def _refresh(self, name: str) -> DomainState | None:
        """Read ``name`` again from the database (once for all who ask meanwhile); the cached
        sessions follow a new state of the same map, or go with another map."""
        running = self._refreshing.get(name)
        if running is None:
            old = self.catalog.find(name)
            running = asyncio.ensure_future(run_in_threadpool(self.catalog.refresh, name))
            self._refreshing[name] = running
            running.add_done_callback(lambda _: self._refreshing.pop(name, None))
            new = await asyncio.shield(running)
            if old is not None and new is not old:
                if new is not None and new.domain.rows_text == old.domain.rows_text:
                    self.registry.retable(new)
                else:
                    self.registry.end_domain(name)
            return new
        return await asyncio.shield(running)

    async def sync_catalog(self) -> None:
        """Every domain as the database holds it, when another worker made or deleted one
        since this worker last looked (``P:catalog``)."""
        raw = await self.redis.get(f"{self.prefix}:catalog")
        epoch = int(raw or 0)
        if epoch == self._catalog_epoch:
            return
        versions = await run_in_threadpool(self.catalog.store.versions)
        for name in sorted(set(versions) | {d.name for d in self.catalog.states()}):
            local = self.catalog.find(name)
            if local is None or versions.get(name) != local.version:
                await self._refresh(name)
        self._catalog_epoch = epoch

    async def domain_changed(self, name: str, version: int, made_or_gone: bool) -> None:
        """This worker changed domain ``name`` (to data ``version``; a deleted domain's last
        version plus one): other workers read it again from their next request that uses it
        (the catalog's epoch goes up too when a domain was made or deleted). With Redis down,
        they are told once it answers again: the change is in the database, and the request
        that made it is acknowledged."""
        try:
            await self._run("version", name, version)
            if made_or_gone:
                await self.redis.incr(f"{self.prefix}:catalog")
        except RedisDown as exc:
            self._owed = True
            log.warning(
                "domain %r changed while Redis is down (%s): told when it is back", name, exc.why
            )

    async def _prepare(self, domain: DomainState, strategy: str) -> None:
        """What ``strategy`` reads of ``domain`` built (in a worker thread, the first time)."""
        entry = strategies.get(strategy)
        if entry.missing(domain.data(POOLED)):
            await run_in_threadpool(self.catalog.prepare, domain, entry.needs)

    # ---- sessions --------------------------------------------------------------------------
    def _lock(self, session_id: str) -> asyncio.Lock:
        lock = self._locks.get(session_id)
        if lock is None:
            if len(self._locks) > 4 * max(len(self.registry), 256):  # unused ones go
                idle = [k for k, v in self._locks.items() if not v.locked()]
                for k in idle[: len(idle) // 2]:
                    del self._locks[k]
            lock = self._locks[session_id] = asyncio.Lock()
        return lock

    async def create(
        self, domain: DomainState, settings: SessionSettings, client: str | None
    ) -> tuple[LiveSession, Decision]:
        self.breaker.check()  # Redis known to be down: nothing built
        for _ in range(ATTEMPTS):
            session, decision = self.registry.create(domain, settings, client)
            now = int(time.time() * 1000)
            got = await self._run(
                "create", session.id, codec.packed(codec.dump(session, replay=False)), domain.name,
                client or "", session.reserved, now, int(self.registry.idle_seconds * 1000),
                *self.limits, _summary(session), domain.version, self._ttl(),
            )  # fmt: skip
            verdict = got[0].decode()
            if verdict == "ok":
                return session, decision
            self.registry.forget(session.id)
            if verdict == "stale":
                domain = await self._at_version(domain.name, int(got[1]))
                await self._prepare(domain, settings.advisor.strategy)
                continue
            if verdict == "sessions":
                raise TooManySessions(self.limits[0])
            if verdict == "memory":
                raise SessionMemoryFull(self.limits[1])
            what = "sessions" if verdict == "client_sessions" else "memory"
            raise ClientQuotaReached(client, what, self.limits[2 if what == "sessions" else 3])
        raise RuntimeError("the domain's prior kept changing while a session was made")

    async def get(self, session_id: str) -> LiveSession:
        cached = self.registry.cached(session_id)
        if cached is not None:
            return cached
        return await self._load(session_id)

    async def _load(self, session_id: str) -> LiveSession:
        got = await self._run("load", session_id, lane=session_id)
        if got[0] != b"ok":
            raise await self._absent(session_id, got)
        return await self._adopt(got[1], int(got[3]))

    async def _adopt(self, blob: bytes, version: int) -> LiveSession:
        """This worker's copy of the session Redis holds as ``blob`` (``version``: the data
        version of its domain's prior there)."""
        try:
            v = codec.peek(codec.unpacked(blob))
        except codec.CodecError as exc:
            log.warning("a session in Redis cannot be read: %s", exc)
            raise SessionUnreadable("?", str(exc)) from None
        try:
            domain = await self._at_version(v["domain"], version)
        except DomainNotFound:
            raise SessionNotFound(v["id"]) from None
        try:
            await self._prepare(domain, v["advisor"]["strategy"])
            session = codec.load(v, domain, 0)
        except (codec.CodecError, ValueError, KeyError, TypeError) as exc:
            log.warning("session %s in Redis cannot be read: %s", v.get("id"), exc)
            raise SessionUnreadable(v.get("id"), str(exc)) from None
        self.registry.put(session)
        return session

    def touch(self, session: LiveSession) -> None:
        """Activity is what the events write (their commit): a read does not keep a session
        alive across workers."""

    def current(self, session: LiveSession) -> LiveSession:
        """This worker's cached copy: an event that found Redis ahead loads a new one."""
        return self.registry.cached(session.id) or session

    async def observe_one(
        self, session: LiveSession, state: int, action: int, next_state: int, step: int = -1
    ) -> Decision:
        moves = (np.array([state]), np.array([action]), np.array([next_state]))
        out = await self._apply(session.id, moves, None if step < 0 else step, one=True)
        return out if isinstance(out, Decision) else out.decisions()[0]

    async def observe(
        self, session: LiveSession, moves: Moves, first_step: int | None = None
    ) -> DecisionBatch:
        out = await self._apply(session.id, moves, first_step)
        assert isinstance(out, DecisionBatch)  # one= is not asked
        return out

    async def _apply(
        self, session_id: str, moves: Moves, first_step: int | None, one: bool = False
    ) -> DecisionBatch | Decision:
        """Apply ``moves`` to the session and write its new state to Redis before answering;
        again from what Redis holds when another worker or a prior update came between.
        While Redis is known to be down, refused before anything is computed (this worker's
        copy stays as Redis holds it)."""
        self.breaker.check()
        async with self._lock(session_id):
            session = self.registry.cached(session_id) or await self._load(session_id)
            for _ in range(ATTEMPTS):
                session, done, rest = await self._replayed(session, moves, first_step)
                if rest is None:
                    assert done is not None
                    return done
                adv = session.advisor
                expected, count, benefit = session.state_step(), adv.advice_count, adv.benefit
                first = adv.steps
                out: DecisionBatch | Decision
                if one and done is None:  # the one-event path, as the local form runs it
                    out = self.registry.observe_one(session, *(int(m[0]) for m in rest))
                    record = codec.decision_record(out, adv.kappa, count, benefit)
                else:
                    out = await self.registry.observe_sliced(session, rest)
                    record = codec.replay_record(out)
                record = codec.packed_record(record)
                try:
                    blob = codec.packed(
                        self.registry.write(session, lambda s: codec.dump(s, replay=False))
                    )
                    got = await self._run(
                        "commit", session_id, expected, session.state_step(),
                        blob, record, adv.steps - first,
                        session.domain.version, int(time.time() * 1000), self.replay_steps,
                        _summary(session), self._ttl(), lane=session_id,
                    )  # fmt: skip
                except BaseException:  # not written (or not known to be): this copy is ahead
                    self.registry.forget(session_id)
                    raise
                verdict = got[0]
                if verdict == b"ok":
                    if done is None:
                        return out
                    assert isinstance(out, DecisionBatch)
                    return joined([done, out])
                if verdict in (b"gone", b"lost"):
                    raise await self._absent(session_id, got)
                self.registry.forget(session_id)  # this copy went ahead of what Redis holds
                session = await self._adopt(got[1], int(got[3]))
            raise RuntimeError(f"session {session_id} kept changing while its events were applied")

    async def _replayed(
        self, session: LiveSession, moves: Moves, first_step: int | None
    ) -> tuple[LiveSession, DecisionBatch | None, Moves | None]:
        """As :meth:`SessionRegistry.replayed`, from the decisions Redis keeps (what any worker
        answered), and the session to go on with: a step out of turn is checked against what
        Redis holds, not against this worker's copy."""
        if first_step is None or first_step == session.advisor.steps + 1:
            return session, None, moves
        session = await self._load(session.id)  # this copy may be behind: Redis decides
        steps = session.advisor.steps
        batches: list[DecisionBatch] = []
        if first_step <= steps:  # a retry: the decisions Redis keeps
            key = f"{self.prefix}:r:{session.id}"
            older, newer = await self.redis.mget(key + ":old", key)
            width = session.domain.domain.n_actions
            batches = codec.read_packed_records((older or b"") + (newer or b""), width)
        done, rest = retried(
            session.id, steps, first_step, moves, lambda first, n: _covering(batches, first, n),
            sum(len(b) for b in batches),
        )  # fmt: skip
        return session, done, rest

    async def describe(self, session: LiveSession) -> SessionSnapshot:
        fresh = await self._load(session.id)
        return self.registry.describe(fresh)

    async def end(self, session: LiveSession) -> SessionSnapshot:
        fresh = await self._load(session.id)
        final = self.registry.describe(fresh)
        if not await self._run("end", session.id):
            raise SessionNotFound(session.id)
        self.registry.forget(session.id)
        return final

    async def snapshot(self, limit: int | None, domain: str | None = None) -> list[SessionSnapshot]:
        """The ``limit`` most recently active sessions of every worker (of ``domain``)."""
        live = f"{self.prefix}:live"
        if domain is None:
            ids = await self.redis.zrevrange(live, 0, -1 if limit is None else limit - 1)
        else:
            members = list(await self.redis.smembers(f"{self.prefix}:dom:{domain}"))  # type: ignore[misc]
            scores = await self.redis.zmscore(live, members) if members else []
            ranked = sorted(
                (sc, m) for sc, m in zip(scores, members, strict=True) if sc is not None
            )[::-1]
            ids = [m for _, m in ranked[:limit]]
        if not ids:
            return []
        async with self.redis.pipeline(transaction=False) as pipe:
            for sid in ids:
                pipe.hget(f"{self.prefix}:s:{sid.decode()}", "blob")
            blobs = [b for b in await pipe.execute() if b is not None]  # None: ended meanwhile
        peeked = []
        for b in blobs:
            try:
                peeked.append(codec.peek(codec.unpacked(b)))
            except codec.CodecError:  # kept by a version this one cannot read: not listed
                continue
        ready: dict[tuple[str, str], DomainState | None] = {}
        for v in peeked:  # what their strategies read of their domains, built
            key = (v["domain"], v["advisor"]["strategy"])
            if key not in ready:
                try:
                    ready[key] = self.catalog.get(key[0])
                    await self._prepare(ready[key], key[1])  # type: ignore[arg-type]
                except (DomainNotFound, ValueError):  # gone, or a strategy not known here
                    ready[key] = None

        def made() -> list[SessionSnapshot]:
            out = []
            for v in peeked:
                domain = ready[(v["domain"], v["advisor"]["strategy"])]
                if domain is None:
                    continue
                try:
                    out.append(self.registry.describe(codec.load(v, domain, 0)))
                except (codec.CodecError, ValueError, KeyError, TypeError):
                    continue  # its domain's map was replaced meanwhile, or unreadable here
            return out

        return await run_in_threadpool(made)

    async def aggregates(self) -> dict[str, Aggregate]:
        rows = await self.redis.hvals(f"{self.prefix}:sum")  # type: ignore[misc]
        out: dict[str, Aggregate] = {}
        for row in rows:
            name, steps, decisions, advice, p = row.decode().rsplit("|", 4)
            agg = out.setdefault(name, Aggregate())
            agg.sessions += 1
            agg.steps += int(steps)
            agg.decisions += int(decisions)
            agg.advice += int(advice)
            agg.looking_lost += float(p) < 0.5
        return out

    async def count_by_domain(self) -> dict[str, int]:
        names = [d.name for d in self.catalog.states()]
        async with self.redis.pipeline(transaction=False) as pipe:
            for name in names:
                pipe.scard(f"{self.prefix}:dom:{name}")
            counts = await pipe.execute()
        return {n: int(c) for n, c in zip(names, counts, strict=True) if c}

    async def count(self) -> int:
        return int(await self.redis.zcard(f"{self.prefix}:live"))

    async def retable(self, domain: DomainState) -> None:
        self.registry.retable(domain)
        await self.domain_changed(domain.name, domain.version, made_or_gone=False)

    async def end_domain(self, name: str) -> int:
        self.registry.end_domain(name)
        return int(await self._run("end_domain", name))

    async def sweep(self) -> None:
        """Idle sessions go (every worker's), and Redis hears of a domain's change it was not
        told of when it failed."""
        if self._owed:
            await self._tell_versions()
        now = int(time.time() * 1000)
        gone = await self._run("expire", now, int(self.registry.idle_seconds * 1000), SWEEP_BATCH)
        for sid in gone:
            self.registry.forget(sid.decode())
        self.registry.expire()
        self.registry.forget_old()

    async def close(self) -> None:
        await self.breaker.close()
        await self.redis.aclose()
        for lane in self._lanes:
            await lane.close()

    async def mute(self, session: LiveSession, muted: bool) -> None:
        """Mute (or unmute) the session and write its state to Redis: a commit of no step (the
        step Redis holds must be the copy's; else the copy is read again and muted again)."""
        session_id = session.id
        async with self._lock(session_id):
            for _ in range(ATTEMPTS):
                copy = self.registry.cached(session_id) or await self._load(session_id)
                expected = copy.state_step()
                self.registry.mute(copy, muted)
                copy.revision += 1
                blob = codec.packed(self.registry.write(copy, lambda s: codec.dump(s, False)))
                got = await self._run(
                    "commit", session_id, expected, copy.state_step(), blob, b"", 0,
                    copy.domain.version,
                    int(time.time() * 1000), self.replay_steps, _summary(copy), self._ttl(),
                    lane=session_id,
                )  # fmt: skip
                if got[0] == b"ok":
                    session.muted = muted  # the caller's copy, if another
                    return
                self.registry.forget(session_id)
                if got[0] == b"gone":
                    raise SessionNotFound(session_id)
        raise RuntimeError(f"session {session_id} kept changing while it was muted")

    def save(self, store: Store) -> int:
        """Nothing to keep at a shutdown: the sessions are in Redis."""
        return 0

    def restore(self, store: Store) -> int:
        """Nothing to read back at a start: the sessions are in Redis."""
        return 0


def _covering(batches: list[DecisionBatch], first: int, n: int) -> DecisionBatch | None:
    """Decisions of steps ``first`` .. ``first + n - 1`` from consecutive kept batches."""
    parts = []
    want = first
    for b in batches:
        lo, hi = b.first_step, b.first_step + len(b)
        if hi <= want or want >= first + n:
            continue
        if lo > want:
            return None
        a = want - lo
        z = min(hi, first + n) - lo
        parts.append(part(b, a, z))
        want = lo + z
    if want != first + n:
        return None
    return joined(parts) if len(parts) > 1 else parts[0]
