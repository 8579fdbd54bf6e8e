"""A live session as bytes and back, exactly: what another worker (through Redis) or the same
service after a restart (through the database) needs to go on with it.

The advisor's state is every slot of its class (the core's numbers: sums, counters, position,
goals ruled out, a random rule's generator) except what the domain shares (the tables, the
per-goal counts, the guide map), which the loading side attaches from its own catalog. A
window of pair keys (:class:`~app.strategies.stream.KeyedWindow`) is written as its keys
with the value each pair added (the numbers the core's ring holds), so the loaded advisor
removes exactly what the saved one would have removed, whatever tables the loading side has
by then. Everything is written with msgspec's MessagePack: float64 stays float64, so the
decisions after a load equal those of the session that never left memory, bit for bit
(``tests/service/live/test_codec.py``).

Nothing of the token is kept but its SHA-256 digest; a loaded session has no plaintext token.
"""

from __future__ import annotations

import functools
import hashlib
import json
import struct
import time
import weakref
from array import array
from datetime import datetime
from typing import Any

import lz4.block
import msgspec
import numpy as np
import numpy.typing as npt

from app import strategies
from app.advice.advisor import Advisor, Decision, DecisionBatch
from app.advice.guide import GuideAdvisor, upgraded_compliance, upgraded_evidence
from app.advice.models import AdviceTables
from app.domain.building import Domain
from app.service.data.domains import DomainState
from app.service.live.history import AdviceLog, Recent
from app.service.live.registry import RECENT_ADVICE, Budget, LiveSession
from app.service.live.replay import Replay
from app.strategies.stream import KeyedWindow

FORMAT = 1
#: slots the loading side attaches or derives
_SHARED = frozenset({"tables", "priors", "guide", "_lam", "_theta_w", "_params", "_rng", "_rule"})
#: a window of pair keys, written in its own form (:meth:`KeyedWindow.window_state`)
_KEYED = frozenset({
    "_ring", "_goal_ring", "_keys", "_kept", "_old", "_n_kept", "_keys_tables",
    "_goal_arrays", "_goal_kept", "_goal_old", "_goal_n_kept",
})  # fmt: skip

_encoder = msgspec.msgpack.Encoder()
_decoder = msgspec.msgpack.Decoder()


class CodecError(ValueError):
    """Bytes that are not a session this service can load (another format or domain)."""


_SLOTS: dict[type, list[str]] = {}


_DIGESTS: weakref.WeakKeyDictionary[Domain, bytes] = weakref.WeakKeyDictionary()


def map_digest(grid: Domain) -> bytes:
    """What a session keeps of its map: the SHA-256 of its rows (a session loaded on another
    map of the same name is refused), made once a map."""
    digest = _DIGESTS.get(grid)
    if digest is None:
        digest = _DIGESTS[grid] = hashlib.sha256("\n".join(grid.rows_text).encode()).digest()
    return digest


def _slots(obj: object) -> list[str]:
    """The slots of ``obj``'s class that :func:`advisor_state` writes (found once a class)."""
    names = _SLOTS.get(type(obj))
    if names is None:
        names = []
        skip = _SHARED | _KEYED if isinstance(obj, KeyedWindow) else _SHARED
        for cls in type(obj).__mro__:
            for name in getattr(cls, "__slots__", ()):
                if name not in names and name not in skip:
                    names.append(name)
        _SLOTS[type(obj)] = names
    return names


_PLAIN_TYPES = frozenset({int, float, bool, str, type(None)})


def _value(v: Any) -> Any:
    """A slot's value in MessagePack's types; tuples and arrays tagged to come back as such."""
    if type(v) in _PLAIN_TYPES:  # most slots: numbers
        return v
    if isinstance(v, np.ndarray):
        return {"nd": v.dtype.str, "shape": list(v.shape), "data": v.tobytes()}
    if isinstance(v, tuple):
        return {"tuple": [_value(x) for x in v]}
    if isinstance(v, list):
        return [_value(x) for x in v]
    if v is None or isinstance(v, bool | int | float | str):
        return v
    raise TypeError(f"cannot write a {type(v).__name__} slot")


def _unvalue(v: Any) -> Any:
    if isinstance(v, dict):
        if "nd" in v:
            return np.frombuffer(v["data"], dtype=v["nd"]).reshape(v["shape"]).copy()
        return tuple(_unvalue(x) for x in v["tuple"])
    if isinstance(v, list):
        return [_unvalue(x) for x in v]
    return v


def advisor_state(adv: Advisor) -> dict[str, Any]:
    """The advisor's own state (no shared table) in MessagePack's types."""
    out: dict[str, Any] = {
        "strategy": adv.strategy,
        "params": adv.params(),
        "slots": {name: _value(getattr(adv, name)) for name in _slots(adv)},
    }
    if isinstance(adv, KeyedWindow):  # a window of pair keys, in its own form
        out.update(adv.window_state())
    rng = getattr(adv, "_rng", None)
    if rng is not None:  # a random rule's draws go on where they were
        out["rng"] = json.dumps(rng.bit_generator.state)
    return out


def restore_advisor(state: dict[str, Any], domain: DomainState, table_key: str) -> Advisor:
    """An advisor in the state :func:`advisor_state` wrote, on ``domain``'s current tables
    (CodecError for a strategy this service does not know, or a state that does not fit)."""
    slots = state["slots"]
    try:
        entry = strategies.get(state["strategy"])
        settings = entry.settings(slots["kappa"], slots["window"], state["params"])
    except ValueError as exc:
        raise CodecError(str(exc)) from None
    if table_key not in domain.view.tables:
        raise CodecError(f"domain {domain.name!r} has no prior table {table_key!r}")
    adv = entry.service_advisor(domain.data(table_key), settings)
    for name, v in slots.items():
        setattr(adv, name, _unvalue(v))
    if isinstance(adv, GuideAdvisor):  # written before undone advice was followed, the
        adv._comply = upgraded_compliance(adv._comply)  # advice budget, the lost models LA, LS
        adv._loglik = upgraded_evidence(adv._loglik, adv.guide.n_goals)
    if isinstance(adv, KeyedWindow):
        try:
            adv.restore_window(state)
        except ValueError as exc:
            raise CodecError(str(exc)) from None
    if "rng" in state:
        rng = np.random.default_rng()
        rng.bit_generator.state = json.loads(state["rng"])
        adv._rng = rng  # type: ignore[attr-defined]  # the random rule's generator
    return adv


def _ring(r: Recent | None) -> dict[str, Any] | None:
    if r is None:
        return None
    return {"code": r._buf.typecode, "buf": r._buf.tobytes(), "count": r._count}


def _unring(v: dict[str, Any] | None) -> Recent | None:
    if v is None:
        return None
    r = Recent.__new__(Recent)
    buf: array[Any] = array(v["code"])
    buf.frombytes(v["buf"])
    r._buf, r._count = buf, v["count"]
    return r


def _advice_log(log: AdviceLog | None) -> dict[str, bytes] | None:
    return None if log is None else log.written()


def _unadvice_log(v: dict[str, bytes] | None, tables: AdviceTables) -> AdviceLog | None:
    return None if v is None else AdviceLog.read(RECENT_ADVICE, v, tables)


#: a record's head: its first step, kappa, the advice count and benefit before it, its length
_HEAD = struct.Struct("<qdqdI")
_I4, _F8 = struct.Struct("<i"), struct.Struct("<d")
#: a piece of advice of 4 actions, or 6 on a map of several floors
_ADVICE = {4: struct.Struct("<4d"), 6: struct.Struct("<6d")}


def replay_record(b: DecisionBatch) -> bytes:
    """One batch of decisions as bytes (what a retry of its steps is answered): a head, then
    the columns that the others follow from: the running advice count and benefit are the
    figures before it plus, one decision at a time, what each advised one added (as the
    advisor adds them up: ``np.add.accumulate`` gives the same bits). Records written one
    after another are read back by :func:`read_replay_records` (each one's length follows
    from its head and its advise column)."""
    n = len(b)
    return b"".join((
        _HEAD.pack(b.first_step, b.kappa, b.count_before, b.benefit_before, n),
        b.state.astype("<i4").tobytes(), b.advise.astype(np.uint8).tobytes(),
        b.kl.astype("<f8").tobytes(), b.p_normal.astype("<f8").tobytes(),
        b.advice.astype("<f8").tobytes(),
    ))  # fmt: skip


def decision_record(d: Decision, kappa: float, count_before: int, benefit_before: float) -> bytes:
    """:func:`replay_record` of one decision, without making a batch of it (the one-event
    path: numpy arrays of one cost more than the rest)."""
    given = d.advice if d.advise else None
    advice = b"" if given is None else _ADVICE[len(given)].pack(*given)
    return b"".join((
        _HEAD.pack(d.step, kappa, count_before, benefit_before, 1),
        _I4.pack(d.state), b"\x01" if d.advise else b"\x00", _F8.pack(d.kl),
        _F8.pack(d.p_normal), advice,
    ))  # fmt: skip


def _read_record(raw: bytes, at: int, width: int) -> tuple[DecisionBatch, int]:
    """The record that starts at ``at`` of ``raw`` (advice of ``width`` actions: the
    session's domain's), and where the next one starts."""
    if len(raw) - at < _HEAD.size:
        raise CodecError("a decision record cut short")
    first, kappa, count_before, benefit_before, n = _HEAD.unpack_from(raw, at)
    at += _HEAD.size

    def column(dtype: str, size: int) -> npt.NDArray[Any]:
        nonlocal at
        out = np.frombuffer(raw, dtype=dtype, count=size, offset=at).copy()
        at += out.nbytes
        return out

    try:
        state = column("<i4", n).astype(np.int64)
        advise = column("u1", n).astype(np.bool_)
        kl, p = column("<f8", n), column("<f8", n)
        advice = column("<f8", width * int(np.count_nonzero(advise))).reshape(-1, width)
    except ValueError as exc:  # frombuffer past the end
        raise CodecError("a decision record cut short") from exc
    count = count_before + np.cumsum(advise, dtype=np.int64)
    gains = np.concatenate([[benefit_before], np.where(advise, kl, 0.0)])
    batch = DecisionBatch(
        first, state, advise, kl, p, count, np.add.accumulate(gains)[1:], advice, kappa,
        count_before, benefit_before, None,
    )  # fmt: skip
    return batch, at


def read_replay_record(raw: bytes, width: int = 4) -> DecisionBatch:
    """The batch :func:`replay_record` (or :func:`decision_record`) wrote, of advice of
    ``width`` actions."""
    batch, end = _read_record(raw, 0, width)
    if end != len(raw):
        raise CodecError("bytes after a decision record")
    return batch


def read_replay_records(raw: bytes, width: int = 4) -> list[DecisionBatch]:
    """The batches of records written one after another, in their order."""
    out, at = [], 0
    while at < len(raw):
        batch, at = _read_record(raw, at, width)
        out.append(batch)
    return out


#: packed data: a first byte saying how the rest is written
_PLAIN, _LZ4 = b"\x00", b"\x01"
#: shorter data is not worth compressing (a one-event record, about 90 bytes)
_PACK_FROM = 256
_FRAME = struct.Struct("<I")


def packed(data: bytes) -> bytes:
    """``data`` as Redis keeps it: LZ4-compressed behind a byte that says so (short data as it
    is). A session's state and its decisions repeat the few values of a map's tables: a
    window-300 state of 11 kB and a 500-decision record of 27 kB become about 2 kB each, in
    about 10 us, so a commit sends Redis a tenth of the bytes."""
    if len(data) < _PACK_FROM:
        return _PLAIN + data
    out: bytes = lz4.block.compress(data, store_size=True)
    return _LZ4 + out


def unpacked(raw: bytes) -> bytes:
    """The data :func:`packed` wrote (a state written before packing, plain MessagePack, as it
    is)."""
    head = raw[:1]
    if head == _LZ4:
        try:
            out: bytes = lz4.block.decompress(raw[1:])
        except lz4.block.LZ4BlockError as exc:
            raise CodecError("packed data that does not decompress") from exc
        return out
    if head == _PLAIN:
        return raw[1:]
    if head and head[0] >= 0x80:  # a MessagePack map: a session state from before packing
        return raw
    raise CodecError("not packed data of this format")


def packed_record(record: bytes) -> bytes:
    """A decisions record (:func:`replay_record`) as Redis appends it to the session's others:
    :func:`packed`, behind its length."""
    data = packed(record)
    return _FRAME.pack(len(data)) + data


def read_packed_records(raw: bytes, width: int = 4) -> list[DecisionBatch]:
    """The batches of records :func:`packed_record` wrote one after another, in their order
    (advice of ``width`` actions)."""
    out, at = [], 0
    while at < len(raw):
        if len(raw) - at < _FRAME.size:
            raise CodecError("a decision record cut short")
        (n,) = _FRAME.unpack_from(raw, at)
        at += _FRAME.size
        if len(raw) - at < n:
            raise CodecError("a decision record cut short")
        out.extend(read_replay_records(unpacked(raw[at : at + n]), width))
        at += n
    return out


@functools.lru_cache(maxsize=4096)
def _iso(when: datetime) -> str:
    """``when.isoformat()``, made once a session (written at every commit)."""
    return when.isoformat()


def dump(session: LiveSession, replay: bool = True) -> bytes:
    """``session`` as bytes (its token as a digest only). ``replay``: with the decisions kept
    for retries (the Redis form keeps those apart)."""
    mono, wall = time.monotonic(), time.time()
    s = session
    out = {
        "format": FORMAT, "id": s.id, "token_digest": s.token_digest, "domain": s.domain.name,
        "map": map_digest(s.domain.domain), "agent_type": s.agent_type,
        "table_key": s.table_key,
        "position": s.position, "p_normal": s.p_normal, "created_at": _iso(s.created_at),
        "last_seen": wall - (mono - s.last_seen), "born": wall - (mono - s.born),
        "sizes": list(s.sizes), "client": s.client, "reserved": s.reserved,
        "path": _ring(s.path), "p_history": _ring(s.p_history), "path_times": _ring(s.path_times),
        "advice_log": _advice_log(s.advice_log), "advisor": advisor_state(s.advisor),
        "replay": s.replay.state() if replay else None,
        "budget": None if s.budget is None else [s.budget.total, s.budget.per_minute],
        "tokens": s.tokens, "tokens_at": s.tokens_at, "muted": s.muted, "revision": s.revision,
    }  # fmt: skip
    return _encoder.encode(out)


def peek(raw: bytes) -> dict[str, Any]:
    """The decoded fields of a dumped session (for its id, domain and times, without loading
    its advisor)."""
    v: dict[str, Any] = _decoder.decode(raw)
    if not isinstance(v, dict) or v.get("format") != FORMAT:
        raise CodecError("not a session of this format")
    return v


def load(raw: bytes | dict[str, Any], domain: DomainState, replay_steps: int) -> LiveSession:
    """The session ``raw`` holds, on ``domain`` (the domain of its name now: CodecError if
    its map is another); its idle time goes on from when it was written."""
    v = raw if isinstance(raw, dict) else peek(raw)
    if v["domain"] != domain.name or v["map"] != map_digest(domain.domain):
        raise CodecError(f"session {v['id']} belongs to another map of domain {v['domain']!r}")
    table_key = v["table_key"] if v["table_key"] in domain.view.tables else "*"
    advisor = restore_advisor(v["advisor"], domain, table_key)
    mono, wall = time.monotonic(), time.time()
    session = LiveSession(
        v["id"], "", domain, v["agent_type"], table_key, advisor, v["position"], v["p_normal"],
        datetime.fromisoformat(v["created_at"]), mono - (wall - v["last_seen"]),
        (v["sizes"][0], v["sizes"][1]), _unring(v["path"]), _unring(v["p_history"]),
        _unadvice_log(v["advice_log"], advisor.tables), client=v["client"],
        reserved=v["reserved"], born=mono - (wall - v["born"]),
        path_times=_unring(v["path_times"]), token_digest=v["token_digest"],
        replay=Replay.of(replay_steps, v["replay"], domain.domain.n_actions),
        # written since advice budgets came: a session written before has none
        budget=None if v.get("budget") is None else Budget(*v["budget"]),
        tokens=v.get("tokens", 0.0), tokens_at=v.get("tokens_at", 0.0),
        muted=v.get("muted", False), revision=v.get("revision", 0),
    )  # fmt: skip
    return session
