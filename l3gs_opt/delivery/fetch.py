"""A client that streams a bundle from a :mod:`l3gs_opt.delivery.server` over real HTTP, slot by slot,
deciding what to ask for exactly as the simulator's client does.

The seam: the simulator's :class:`~l3gs_opt.simulator.client.Client` predicts, values and
schedules (nothing of that is repeated here); only its delivery is replaced. Each slot ``t``:

1. ``Client.slot_inputs`` / ``begin_slot`` / ``plan``: the requested units, in order, from the
   predicted viewport and the bytes *measured* in earlier slots (the bandwidth history).
2. The units go to the wire (:class:`HttpLink`, an aiohttp client on its own thread): first the
   unit cut off at the end of the last slot, then the requests in order, one after the other,
   each as HTTP Range requests of its chunks (a unit of several chunks -- the ``scene`` view, a
   ``distill`` layer in the ``object`` view -- is its chunks in index order).
3. At the slot's wall-clock end the wire is cut: the bytes that arrived per unit in the slot are
   read off, the requests not started are dropped, a request started in the slot with no byte
   yet is aborted (with ``SimConfig.carry="head"`` the first request not finished is kept open
   instead, whether a byte of it arrived or not), and the unit being received carries over (it
   keeps streaming while the client renders and plans). ``Client.deliver(ids, measured)`` then runs the simulator's link model with
   the measured bytes as the slot's share, which reproduces the wire's per-unit bytes exactly
   (the same sequential order): this is checked every slot, so the records, the rendering and
   the next prediction rest on what really arrived.
4. ``Client.end_slot``: render what is held from the true viewpoint, score, record -- deferred
   until the next slot's requests are out (a client plans first and draws while they stream; the
   seconds between a slot's start and its requests, ``late_s``, are link time the carried-over
   unit alone can use, which the simulator's link does not model).

So given the same bytes per slot, ``fetch`` asks for the same chunks in the same order as
``simulate`` (``tests/test_delivery.py`` checks it); what differs is where the bytes come from.

What the client knows before slot 0 (the catalogue)
---------------------------------------------------
The simulator's client values splats it does not hold (Eq. 1 needs their positions and scales),
so it knows the whole bundle from the start. Here that knowledge is fetched: the bundle is rebuilt
from the server's ``index.json`` by :func:`l3gs_opt.scene.stream_index.stream_bundle`, whose chunk
fetch is an HTTP Range request (hash-checked) sent without a session name: not charged to the
streaming session's trace (a server paces such requests per connection, or not at all when started
with ``shape_anonymous=False``). The catalogue is
used to value and to render rows by number; what is *shown* is decided only by the bytes that
arrived on the streaming session, and those bytes are checked against the catalogue's (every
slot) and against the index's SHA-256 (when a chunk completes).

Differences from ``simulate`` (beyond real time)
------------------------------------------------
* A chunk arrives in its file order, not re-sorted by predicted utility: the run's config gets
  ``splat_order="stored"`` (``simulate --splat-order stored`` models exactly that), and a partly
  received unit shows the prefix of its rows in the bundle's order (by default ``simulate`` shows
  the most useful ones). A partly received unit of several chunks shows ``bytes // bytes per
  splat`` rows, as the simulator counts them.
* ``bytes_share`` (and so the predictor's history) is the bytes that arrived, not the trace's:
  when the client has nothing left to ask for, the slot's idle capacity is not seen.
* ``substeps > 1`` (re-planning within a slot) is not supported.

Records: ``OUT/slots.jsonl`` and ``OUT/summary.jsonl`` as ``simulate`` writes them (same keys),
plus per slot ``fetch``: ``{"bytes_received", "late_s", "cut_late_s", "retries"}`` (seconds after
the slot's start its requests went out; seconds after the slot's end its bytes were counted -- the
previous slot's picture is drawn in between, so a draw longer than the slot's rest makes the slot
longer -- and connection retries). ``OUT/index.json`` is the fetched index and ``OUT/fetched/cN.bin`` the bytes
received of chunk N, which ``resume`` reloads (after the recorded slots are replayed through the
link model) before it continues the unit that was in flight.
"""

from __future__ import annotations

import asyncio
import dataclasses
import sys
import threading
import time
import uuid
from collections import OrderedDict, deque
from pathlib import Path
from typing import Optional, Sequence


import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.scene.bundle import Bundle
from l3gs_opt.scene.stream_index import INDEX_NAME, StreamChunk, StreamIndex, load_stream_chunk, read_stream, \
    stream_bundle
from l3gs_opt.simulator.client import Client
from l3gs_opt.simulator.config import SimConfig

__all__ = ["FetchError", "unit_chunks", "HttpLink", "fetch", "FETCH_DIR", "REQUEST_TIMEOUT_S", "RETRY_S",
           "MAX_RETRY_S", "MIN_SLOT_S", "CATALOGUES"]

FETCH_DIR = "fetched"
#: Seconds to wait for the index or a catalogue chunk, and for a connection to open.
REQUEST_TIMEOUT_S = 60.0
#: Seconds a transfer keeps retrying after its connection fails (a server restart, a dropped
#: connection) without receiving a byte, before the fetch fails. Retries start 0.1 s apart and back
#: off to 2 s; each resumes the chunk from the first byte not yet received (a Range request).
RETRY_S = 30.0
#: Largest ``retry_s`` (seconds): a server restart takes seconds; a longer wait is a typo that would
#: leave a fetch hanging (for years at 1e12) instead of failing.
MAX_RETRY_S = 3600.0
#: Shortest slot (seconds): a slot is wall-clock time, cut by a sleeping thread; below 10 ms the cut
#: is lost in timer and scheduling jitter (and the server's default burst is 1 % of a 1 s slot).
MIN_SLOT_S = 0.01
_RETRY_FIRST_S, _RETRY_MAX_S = 0.1, 2.0
_READ_BYTES = 64 * 1024


class FetchError(L3gsError, ValueError):
    """A fetch failed (bad URL or answer, bytes that do not match the index, records from another
    run); names the field and the index (slot or chunk) where one is at fault."""

    def __init__(self, field: str, message: str, index: Optional[int] = None):
        self.field = field
        self.index = index
        super().__init__(f"{field}{'' if index is None else f'[{index}]'}: {message}")


def unit_chunks(index: StreamIndex, cat) -> list[tuple[StreamChunk, ...]]:
    """The chunks (non-empty, in index order) whose bytes make up each unit of catalogue ``cat``.

    Raises
    ------
    FetchError
        A unit whose chunks' bytes do not add up to its size (naming the unit).
    """
    objects = [o.id for o in index.objects] if index.segmented else None
    out = []
    for k in range(cat.units):
        lab = cat.label(k)
        j, lv = lab[0], lab[1]

        def wanted(c: StreamChunk) -> bool:
            if c.bytes == 0 or c.level != lv:
                return False
            if cat.view != "scene" and objects is not None and c.object != objects[j]:
                return False
            if cat.view == "distill":
                return c.sh_form == cat.forms[lab[2]]
            return True

        mine = tuple(c for c in index.chunks if wanted(c))
        if sum(c.bytes for c in mine) != int(cat.bytes[k]):
            raise FetchError("units", f"{lab}: its chunks hold {sum(c.bytes for c in mine)} bytes, the catalogue "
                                      f"says {int(cat.bytes[k])}", k)
        out.append(mine)
    return out


class _Store:
    """Bytes received per chunk, in memory and (with a folder) in ``FOLDER/cN.bin``."""

    def __init__(self, folder: Optional[Path], n: int):
        self.folder = folder
        self.data = [bytearray() for _ in range(n)]
        if folder is not None:
            folder.mkdir(parents=True, exist_ok=True)

    def _path(self, i: int) -> Path:
        return self.folder / f"c{i}.bin"

    def append(self, i: int, data: bytes) -> None:
        self.data[i] += data
        if self.folder is not None:
            with open(self._path(i), "ab") as fh:
                fh.write(data)

    def reset(self) -> None:
        for i in range(len(self.data)):
            self.data[i] = bytearray()
            if self.folder is not None:
                self._path(i).unlink(missing_ok=True)

    def reload(self, need: Sequence[int]) -> None:
        """Keep the first ``need[i]`` bytes of each chunk's file (resume); bytes received after the
        last recorded slot's cut are dropped (the unit in flight is fetched again from there)."""
        for i, n in enumerate(need):
            path = None if self.folder is None else self._path(i)
            have = path.read_bytes() if path is not None and path.exists() else b""
            if len(have) < n:
                raise FetchError("resume", f"{len(have)} bytes of chunk {i} on disk, the records need {n}: the "
                                           f"records do not come from this folder's fetch; run without --resume", i)
            self.data[i] = bytearray(have[:n])
            if path is not None:
                path.write_bytes(bytes(self.data[i]))


class HttpLink:
    """The client's side of the wire: one aiohttp session on a background thread, one transfer at a time.

    Parameters
    ----------
    url : str
        The server's base URL (``index.json`` and the data files are under it).
    client : str
        The session name sent as ``X-L3gs-Client`` (the server paces per name).
    retry_s : float
        See :data:`RETRY_S`.
    """

    def __init__(self, url: str, *, client: str, retry_s: float = RETRY_S):
        import aiohttp

        self.url = url.rstrip("/")
        self.client = client
        self._aiohttp = aiohttp
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, name="l3gs-fetch", daemon=True)
        self._thread.start()
        self.session = self._call(self._open())
        self.units: list[tuple[StreamChunk, ...]] = []
        self.store: Optional[_Store] = None
        self.trace_slot = 0                    # the trace slot the session is in (sent to the server)
        self.slot_started: Optional[float] = None   # time.monotonic() at its start
        self.retry_s = float(retry_s)
        self.retries = 0                       # transfers retried after a failed connection, this slot
        self.queue: deque = deque()            # [unit, bytes of it held], the head being received
        self.slot_bytes: OrderedDict = OrderedDict()
        self.fresh: set = set()                # units requested in this slot
        self.carry = "started"                 # SimConfig.carry: what a cut keeps on the wire
        self.error: Optional[BaseException] = None
        self._task: Optional[asyncio.Task] = None
        self._wake: Optional[asyncio.Event] = None

    # -- plumbing -------------------------------------------------------------------------
    def _call(self, coro, timeout_s: Optional[float] = REQUEST_TIMEOUT_S):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout_s)

    async def _open(self):
        aiohttp = self._aiohttp
        timeout = aiohttp.ClientTimeout(total=None, sock_connect=REQUEST_TIMEOUT_S)
        return aiohttp.ClientSession(timeout=timeout, connector=aiohttp.TCPConnector(limit=4))

    def close(self) -> None:
        """Abort any transfer, close the session and stop the thread (idempotent)."""
        if not self._thread.is_alive():
            return

        async def shut():
            if self._task is not None:
                self._task.cancel()
                await asyncio.gather(self._task, return_exceptions=True)
            await self.session.close()

        try:
            self._call(shut(), 10.0)
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(10.0)
            self.loop.close()

    async def _get(self, path: str, rng: Optional[tuple[int, int]], name: Optional[str]):
        headers = {} if name is None else {"X-L3gs-Client": name}
        if rng is not None:
            headers["Range"] = f"bytes={rng[0]}-{rng[1] - 1}"
        if name == self.client:
            # Read by the server on a session's first request only: after a server restart the new
            # session's trace clock starts at the slot the client is in, not at the run's start,
            # and as long ago as this slot began on the client's clock.
            headers["X-L3gs-Trace-Slot"] = str(self.trace_slot)
            if self.slot_started is not None:
                headers["X-L3gs-Session-Age"] = f"{max(0.0, time.monotonic() - self.slot_started):.6f}"
        return self.session.get(f"{self.url}/{path}", headers=headers)

    async def _read_all(self, path: str, rng: Optional[tuple[int, int]], name: str) -> bytes:
        async with await self._get(path, rng, name) as resp:
            want = 200 if rng is None else 206
            if resp.status != want:
                raise FetchError("url", f"GET {self.url}/{path} ({'whole' if rng is None else rng}) answered "
                                        f"{resp.status}, expected {want}")
            return await resp.read()

    def get(self, path: str, rng: Optional[tuple[int, int]] = None, *, name: Optional[str] = None) -> bytes:
        """The body of ``GET URL/path`` (``rng``: bytes ``[start, end)``, expecting 206), synchronously;
        sent under the session ``name`` (None: no name, as the catalogue is fetched)."""
        try:
            return self._call(self._read_all(path, rng, name))
        except (OSError, asyncio.TimeoutError, self._aiohttp.ClientError) as exc:
            raise FetchError("url", f"GET {self.url}/{path}: {type(exc).__name__}: {exc}") from None

    # -- the streaming session (all below runs on the loop's thread) -----------------------------
    def begin(self, units: list[tuple[StreamChunk, ...]], store: _Store, *, trace_slot: int,
              carried: Optional[tuple[int, int]] = None, carry: str = "started") -> None:
        """Prepare the session: units' chunks, where bytes go, the trace slot the session starts
        at, the unit in flight (unit, bytes of it held) after a resume, and what a cut keeps
        (``SimConfig.carry``)."""
        self.units, self.store, self.trace_slot, self.carry = units, store, trace_slot, carry

        async def go():
            self._wake = asyncio.Event()
            if carried is not None:
                self.queue.append(list(carried))
            self._task = asyncio.get_running_loop().create_task(self._work())
        self._call(go())

    def submit(self, ids: Sequence[int], *, trace_slot: int, slot_started: Optional[float] = None) -> None:
        """Queue the slot's requests (the session now in trace slot ``trace_slot``, which began at
        ``slot_started`` on ``time.monotonic()``) behind the unit in flight."""
        async def go():
            self.trace_slot, self.slot_started = trace_slot, slot_started
            for k in ids:
                self.queue.append([int(k), 0])
                self.fresh.add(int(k))
            self._wake.set()
        self._call(go())

    def cut(self) -> "tuple[OrderedDict[int, int], int]":
        """End the slot: bytes that arrived per unit (in arrival order), dropping what did not start,
        and the number of connection retries in the slot."""
        async def go():
            if self.error is not None:
                raise self.error
            got, self.slot_bytes = self.slot_bytes, OrderedDict()
            head = self.queue[0] if self.queue else None
            keep = head is not None and (self.carry == "head" or got.get(head[0], 0) + head[1] > 0 and
                                         (got.get(head[0], 0) > 0 or head[0] not in self.fresh))
            if head is not None and not keep:
                # Started with no byte yet (or not started at all): the link model drops it; abort.
                self._task.cancel()
                await asyncio.gather(self._task, return_exceptions=True)
                self._task = asyncio.get_running_loop().create_task(self._work())
            self.queue = deque([head] if keep else [])
            self.fresh = set()
            self.retries, retries = 0, self.retries
            return got, retries
        return self._call(go())

    async def _work(self) -> None:
        try:
            while True:
                if not self.queue:
                    self._wake.clear()
                    await self._wake.wait()
                    continue
                await self._transfer(self.queue[0])
                self.queue.popleft()
        except asyncio.CancelledError:
            raise
        except BaseException as exc:   # noqa: BLE001 - handed to the main thread at the next cut
            self.error = exc if isinstance(exc, L3gsError) else FetchError(
                "url", f"streaming from {self.url}: {type(exc).__name__}: {exc}")

    async def _transfer(self, entry: list) -> None:
        k, held = entry
        base = 0
        for c in self.units[k]:
            lo = max(0, held - base)
            base += c.bytes
            while lo < c.bytes:
                lo = await self._retrying(c, lo, entry, k)

    async def _retrying(self, c: StreamChunk, lo: int, entry: list, k: int) -> int:
        """Receive chunk ``c`` from byte ``lo`` on; a failed connection is retried from the first
        byte missing until :attr:`retry_s` pass without a byte. Returns the bytes of ``c`` held."""
        wait, deadline = _RETRY_FIRST_S, time.monotonic() + self.retry_s
        while True:
            before = lo
            try:
                return await self._receive(c, lo, entry, k)
            except FetchError:
                raise
            except (OSError, asyncio.TimeoutError, self._aiohttp.ClientError) as exc:
                lo = len(self.store.data[c.index])
                if lo > before:   # progress resets the clock: only a dead server runs it out
                    wait, deadline = _RETRY_FIRST_S, time.monotonic() + self.retry_s
                if time.monotonic() + wait > deadline:
                    raise FetchError("chunks", f"GET {self.url}/{c.file}: no byte for {self.retry_s:g} s of retries "
                                               f"({type(exc).__name__}: {exc})", c.index) from None
                self.retries += 1
                await asyncio.sleep(wait)
                wait = min(2 * wait, _RETRY_MAX_S)

    async def _receive(self, c: StreamChunk, lo: int, entry: list, k: int) -> int:
        async with await self._get(c.file, (c.start + lo, c.end), self.client) as resp:
            want = f"bytes {c.start + lo}-{c.end - 1}/"
            if resp.status != 206 or not resp.headers.get("Content-Range", "").startswith(want):
                raise FetchError("chunks", f"GET {c.file} {c.range_header}: answered {resp.status} "
                                           f"{resp.headers.get('Content-Range')!r}, expected 206 {want}...",
                                 c.index)
            async for data in resp.content.iter_chunked(_READ_BYTES):
                if len(data) > c.bytes - lo:
                    raise FetchError("chunks", f"{c.file}: more bytes than the range asked", c.index)
                self.store.append(c.index, data)
                lo += len(data)
                entry[1] += len(data)
                self.slot_bytes[k] = self.slot_bytes.get(k, 0) + len(data)
            if lo != c.bytes:
                # A body cut short (the server went away): retried from here.
                raise self._aiohttp.ClientPayloadError(f"{c.file}: the response ended after {lo} of {c.bytes} bytes")
        return lo


#: What the client knows before slot 0 (``fetch(catalogue=...)``).
CATALOGUES = ("full", "tables")


def _fetch_tables(link: "HttpLink", index_bytes: bytes) -> tuple[dict, int]:
    """The server's utility tables (made from ``index_bytes``) by (utility, view), and the metadata
    bytes read (manifest + files)."""
    from l3gs_opt.delivery.tables import TABLES_NAME, load_table, read_tables

    try:
        raw = link.get(TABLES_NAME)
    except FetchError as exc:
        raise FetchError("catalogue", f"'tables': the server has no {TABLES_NAME} ({exc}); export them with "
                                      "'l3gs-opt bundle tables', or use catalogue 'full'") from None
    tables, total = {}, len(raw)
    for entry in read_tables(raw, index_bytes=index_bytes):
        data = link.get(entry["file"])
        total += len(data)
        tables[(entry["utility"], entry["view"])] = load_table(entry, data)
    return tables, total


def _placeholders(dtype: np.dtype, n: int) -> np.ndarray:
    """``n`` records that render as nothing: opacity and scales far below visible, unit rotation."""
    rec = np.zeros(n, dtype)
    names = dtype.names or ()
    for f in names:
        if f == "opacity" or f.startswith("scale_"):
            rec[f] = _INVISIBLE
    if "rot_0" in names:
        rec["rot_0"] = 1.0
    return rec


#: Logit opacity and log scale of a placeholder: sigmoid(-30) ~ 1e-13, exp(-30) ~ 1e-13 scene units.
_INVISIBLE = -30.0


@dataclasses.dataclass(frozen=True)
class _ReceivedBundle(Bundle):
    """The bundle as far as it arrived: each chunk's received whole records, then placeholders.

    The rows a client shows are the received records (the catalogue's file order), so the
    placeholders are never shown; they keep the rows' numbering (object and level per row) fixed
    from slot 0, when nothing has arrived.
    """

    index: Optional[StreamIndex] = None
    store: Optional[_Store] = None

    def chunk(self, i: int) -> np.ndarray:
        c = self.index.chunks[i]
        dtype = self.index.record(c.sh_form).dtype
        rec = _placeholders(dtype, c.splats)
        have = self.store.data[c.index]
        n = min(c.splats, len(have) // dtype.itemsize)
        if n:
            rec[:n] = np.frombuffer(bytes(have[:n * dtype.itemsize]), dtype=dtype, count=n)
        return rec


class _FetchClient(Client):
    """The simulator's client with this slot's fetch facts in its records."""

    fetch_info: dict = {}

    def _slot_record(self) -> dict:
        record = super()._slot_record()
        if self.fetch_info:
            record["fetch"] = dict(self.fetch_info)
        return record


def _check_received(index: StreamIndex, catalogue: Optional[dict], store: _Store, units, ks, complete) -> None:
    """The bytes received of ``ks`` equal the catalogue's (when there is one); completed units pass
    the index's hashes."""
    for k in ks:
        for c in units[k]:
            have = bytes(store.data[c.index])
            if catalogue is not None and have != catalogue[c.index][:len(have)]:
                raise FetchError("chunks", f"{c.file}: the {len(have)} bytes received differ from the catalogue's "
                                           "(the data changed on the server during the run?)", c.index)
            if complete[k]:
                load_stream_chunk(index, c, have)


def _check_out(out: Path) -> None:
    """Refuse an ``out`` folder that is not a fetch's (new, empty, or a previous fetch's output):
    the records and the fetched index would be written over a bundle's or an export's files."""
    if out.exists() and not out.is_dir():
        raise FetchError("out", f"{out} is a file: expected a folder")
    if (out / "manifest.json").exists():
        raise FetchError("out", f"{out} holds a bundle (manifest.json): fetch into a new or empty folder")
    # A previous fetch's folder holds its index.json next to FETCH_DIR (made first: see fetch()).
    if (out / INDEX_NAME).exists() and not (out / FETCH_DIR).is_dir():
        raise FetchError("out", f"{out} holds a stream export ({INDEX_NAME}) that is not a fetch's: fetch into a new "
                                "or empty folder")


def fetch(url: str, trace, poses, method: str, out_dir=None, *, slots: int = 60, resume: bool = False,
          config: SimConfig = SimConfig(), solver: Optional[str] = None, mbps: Optional[float] = None,
          start: int = 0, trace_format: str = "auto", mapping=None, reference=None, client: Optional[str] = None,
          retry_s: float = RETRY_S, catalogue: str = "full", progress: bool = False):
    """Stream the bundle served at ``url`` for ``slots`` slots with ``method`` (see the module docstring).

    Parameters
    ----------
    url : str
        Base URL of a :mod:`l3gs_opt.delivery.server` (``http://127.0.0.1:8000``).
    trace : trace name or file
        The bandwidth trace the simulator's client would see (bytes per slot for the records and the
        slot-0 prediction); the server paces to its own trace.
    poses : path or PoseTrace
        The viewer's poses (as :class:`~l3gs_opt.simulator.simulation.Simulation` takes them).
    method : str
        A simulator method (``l3gs``, ``bb``, ``sort``, ...); ``solver`` as for ``simulate``.
    out_dir : path, optional
        Records and received bytes (needed for ``resume``).
    slots : int
        Slots to run (of ``config.slot_s`` seconds of wall-clock time each).
    resume : bool
        Continue an interrupted fetch into ``out_dir`` (replays the records, reloads the bytes).
    config : SimConfig
        As for ``simulate`` (``substeps`` must be 1).
    mbps, start, trace_format : as for :func:`l3gs_opt.simulator.simulation.trace_bytes`.
    client : str, optional
        Session name for the server's pacing (default: a random one). Use a new name for every run,
        a resumed one included: the server keeps a session's trace clock running from its first request.
    retry_s : float
        Seconds a transfer retries a failed connection without receiving a byte (:data:`RETRY_S`):
        a server restarted within it is picked up where the chunk stopped, and the run goes on.
    catalogue : {"full", "tables"}
        What the client knows before slot 0 (see the module docstring): ``full``, the whole bundle
        (any utility, as the simulator's client); ``tables``, only the index and the server's
        utility tables (``l3gs-opt bundle tables``; layered bundles, ``utility_mode="table"``).

    Returns
    -------
    SimulationResult
        As :meth:`Simulation.run` returns it.

    Raises
    ------
    FetchError
        Bad URL or answers, bytes that do not match, ``resume`` without ``out_dir`` or with another index, a
        ``slot_s`` below :data:`MIN_SLOT_S`, a ``retry_s`` above :data:`MAX_RETRY_S`, a trace window of 0 bytes,
        an ``out_dir`` that holds a bundle or a stream export other than a previous fetch's.
    SimulationError, StreamError, TraceError
        As ``simulate`` raises them.
    """
    from l3gs_opt.simulator.simulation import Simulation, trace_bytes

    if config.substeps != 1:
        raise FetchError("substeps", f"{config.substeps}: fetch plans once per slot (substeps 1)")
    if config.decision_s:
        raise FetchError("decision_s", f"{config.decision_s}: fetch takes the time it takes to plan (records' "
                                       "late_s); decision_s models it in simulate only")
    # Static chunk files arrive in their stored order (the records say so: simulate with the same
    # config reproduces it).
    config = dataclasses.replace(config, splat_order="stored")
    if catalogue not in CATALOGUES:
        raise FetchError("catalogue", f"{catalogue!r} is not one of {', '.join(CATALOGUES)}")
    if catalogue == "tables":
        if config.last_chunk != "whole":
            # Refused before the catalogue is fetched, not at slot 0: the tables hold no splat's value.
            raise FetchError("last_chunk", f"{config.last_chunk!r} counts a chunk's first splats: the 'tables' "
                                           "catalogue values whole chunks only (use catalogue 'full')")
        config = dataclasses.replace(config, utility_mode="table")
    if resume and out_dir is None:
        raise FetchError("resume", "needs out_dir (the folder of the interrupted fetch)")
    if not isinstance(url, str) or not url.startswith(("http://", "https://")):
        raise FetchError("url", f"{url!r}: expected http://HOST:PORT")
    if not config.slot_s >= MIN_SLOT_S:
        raise FetchError("slot_s", f"{config.slot_s!r}: must be at least {MIN_SLOT_S} s (MIN_SLOT_S): a fetch slot "
                                   "is wall-clock time")
    if not (isinstance(retry_s, (int, float)) and 0 <= retry_s <= MAX_RETRY_S):
        raise FetchError("retry_s", f"{retry_s!r}: expected seconds in [0, {MAX_RETRY_S:g}] (MAX_RETRY_S)")
    if isinstance(out_dir, str) and not out_dir.strip():   # Path("") is the current folder
        raise FetchError("out", f"{out_dir!r} is not a folder name")
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        _check_out(out)
    bandwidth, info = trace_bytes(trace, mbps=mbps, start=start, slots=slots, slot_s=config.slot_s,
                                  format=trace_format)
    if not np.any(np.asarray(bandwidth) > 0):
        # As the server's shaper refuses such a trace: the records would divide by nothing.
        what = "the trace" if mbps is None else f"{mbps!r} Mbit/s"
        raise FetchError("trace" if mbps is None else "mbps",
                         f"{what} gives 0 bytes in every one of the {len(bandwidth)} slots of {config.slot_s!r} s "
                         "(needs at least one slot with bytes > 0)")
    link = HttpLink(url, client=client or f"fetch-{uuid.uuid4().hex[:12]}", retry_s=retry_s)
    try:
        raw = link.get(INDEX_NAME)
        if out is None:
            import tempfile

            holder = tempfile.TemporaryDirectory(prefix="l3gs-fetch-")
            folder = Path(holder.name)
        else:
            holder, folder = None, out
            # Before index.json: marks the folder as a fetch's, so that a rerun may write into it.
            (folder / FETCH_DIR).mkdir(parents=True, exist_ok=True)
        index_path = folder / INDEX_NAME
        if resume and index_path.exists() and index_path.read_bytes() != raw:
            raise FetchError("resume", f"the server's {INDEX_NAME} differs from {index_path}: another bundle; "
                                       "run without --resume")
        tmp = index_path.with_suffix(".json.part")
        tmp.write_bytes(raw)
        tmp.replace(index_path)
        index = read_stream(index_path, check_files=False)
        fetched: dict[int, bytes] = {}

        def catalogue_fetch(c: StreamChunk) -> bytes:
            if c.index not in fetched:
                fetched[c.index] = link.get(c.file, (c.start, c.end)) if c.bytes else b""
            return fetched[c.index]

        store = _Store(None if out is None else out / FETCH_DIR, len(index.chunks))
        info = {**info, "url": url, "client": link.client, "catalogue": catalogue}
        tables = None
        if catalogue == "full":
            bundle = stream_bundle(index, fetch=catalogue_fetch)
        else:
            if index.representation != "layered":
                raise FetchError("catalogue", f"'tables' needs a layered bundle (placeholder rows stand for splats not "
                                              f"yet received), not {index.variant!r}; use catalogue 'full'")
            tables, metadata_bytes = _fetch_tables(link, raw)
            info["metadata_bytes"] = metadata_bytes
            bundle = _ReceivedBundle(path=index.path, manifest=index.bundle_manifest(), index=index, store=store)
            if reference is None:
                # The score's reference is the evaluator's, not the client's knowledge: read apart.
                full = Simulation(stream_bundle(index, fetch=catalogue_fetch), poses, bandwidth, config=config,
                                  mapping=mapping)
                reference = full.reference_scene()
        sim = Simulation(bundle, poses, bandwidth, config=config, reference=reference, mapping=mapping, info=info,
                         utility_tables=tables)
        spec = sim.spec(method, solver)
        if tables is not None and (spec.utility, spec.view) not in tables:
            have = ", ".join(f"{u}/{v}" for u, v in sorted(tables)) or "none"
            raise FetchError("utility", f"{spec.utility!r} for the {spec.view!r} view: the server's tables are "
                                        f"{have} (l3gs-opt bundle tables --utility NAME --views VIEW)")
        cl = _FetchClient(sim, spec, out_dir=out, resume=resume)
        cl.fetch_info = {}
        cat = cl.cat
        units = unit_chunks(index, cat)
        carried = None
        if cl.first_slot == 0:
            store.reset()
        else:
            need = [0] * len(index.chunks)
            for k in range(cat.units):
                left = int(cl.got[k])
                for c in units[k]:
                    need[c.index] = min(c.bytes, max(0, left))
                    left -= c.bytes
            store.reload(need)
            if cl.link.in_flight:
                tr = cl.link.in_flight[0]
                carried = (int(tr.key), int(tr.delivered))
        if tables is not None:
            sim.reload_scene(bundle)
        link.begin(units, store, trace_slot=start + cl.first_slot, carried=carried, carry=config.carry)
        # The references the pictures are scored against, before the clock starts (evaluation work;
        # the first render also compiles the renderer, which would make slot 0's cut late).
        for t in range(cl.first_slot, sim.T):
            sim.reference_image(t)
        t_zero = None
        pending = None          # the last slot's picture: drawn while this slot's requests stream

        def draw() -> None:
            record = pending()
            if progress:
                print(f"slot {record['slot']}: {record['fetch']['bytes_received']} bytes, SSIM {record['ssim']:.4f}",
                      file=sys.stderr, flush=True)

        for t in range(cl.first_slot, sim.T):
            cl.fetch_info = {}
            cl.begin_slot(cl.slot_inputs(t))
            ids = cl.plan()
            now = time.monotonic()
            if t_zero is None:   # the slots' wall clock starts when the first requests go out
                t_zero = now
            slot_start = t_zero + (t - cl.first_slot) * config.slot_s
            link.submit(ids, trace_slot=start + t, slot_started=slot_start)
            late = max(0.0, now - slot_start)
            if pending is not None:
                draw()
            wait = slot_start + config.slot_s - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            cut_late = max(0.0, time.monotonic() - slot_start - config.slot_s)
            got, retries = link.cut()
            measured = int(sum(got.values()))
            cl.deliver(ids, measured)
            d = cl.acc["delivery"]
            if list(d.delivered.items()) != [(k, b) for k, b in got.items() if b > 0]:
                raise FetchError("slots", f"the link model's deliveries {dict(d.delivered)} differ from the bytes "
                                          f"that arrived {dict(got)}", t)
            _check_received(index, fetched if catalogue == "full" else None, store, units, list(d.delivered),
                            cl.complete)
            if tables is not None and d.delivered:
                sim.reload_scene(bundle)
            cl.fetch_info = {"bytes_received": measured, "late_s": round(late, 6), "cut_late_s": round(cut_late, 6),
                             "retries": retries}
            pending = cl.end_slot(defer=True)
        if pending is not None:
            draw()
        result = cl.finish()
        if holder is not None:
            holder.cleanup()
        return result
    finally:
        link.close()
