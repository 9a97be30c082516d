"""An HTTP server for a stream export (:mod:`l3gs_opt.scene.stream_index`): ``index.json`` and its data files.

``GET`` and ``HEAD`` of ``/index.json`` and of each data file the index names
(``filenames``: ``/chunks.bin``, or ``/chunks/o0_l1_full.bin`` ...), and, when the export has
utility tables (:mod:`l3gs_opt.delivery.tables`), of ``/tables.json`` and the table files it lists
(metadata: never paced, like the index), nothing else: any other path
(``..``, its encoded forms, absolute paths, links or files not named by the index) is 404. The
allow-list is read from the index when the server starts, and each file is opened by its path
under the folder resolved then (after links), so a link planted later cannot lead out (restart the
server after exporting again into the same folder: new data file names are not served before).
Every chunk's bytes are checked against the index's sha256 when the server starts (``verify``, on
by default): a corrupt or stale export is refused by name, not served to clients that would then
refuse each chunk in turn.

HTTP semantics (RFC 9110)
-------------------------
* ``Accept-Ranges: bytes`` on every file response.
* ``Range`` (GET only; ignored on HEAD, as section 14.2 requires for methods other than GET):
  one range ``bytes=a-b``, ``bytes=a-`` or ``bytes=-n`` gives ``206 Partial Content`` with
  ``Content-Range: bytes a-b/size`` (``b`` clipped to ``size - 1``; ``-n``: the last ``n``
  bytes). An unsatisfiable range (``a >= size``, ``-0``, any range of an empty file) gives
  ``416`` with ``Content-Range: bytes */size``. A header that does not parse (another unit,
  ``b < a``, junk) is ignored: ``200`` and the whole file. **Several ranges** (``bytes=0-1,4-5``)
  are answered with the whole file and ``200`` (the server may ignore a Range field; a client of
  this server asks one chunk per request, so multipart/byteranges would buy nothing).
* ``ETag``: strong, ``"sha256:<first 32 hex digits of the file's SHA-256>"`` -- the content's hash,
  so an ETag changes exactly when the bytes do (size + mtime would also change on a rewrite of the
  same bytes, and could miss a same-size rewrite within the mtime's resolution). Hashes are cached
  by the open file's (device, inode, size, mtime); a rewritten file is hashed again (in a worker
  thread).
* ``If-None-Match`` (weak comparison, ``*`` matches) gives ``304 Not Modified`` on GET and HEAD,
  before any Range; ``If-Range`` with another ETag (or a date: no dates are served) makes the Range
  ignored.
* Other methods: ``405`` with ``Allow: GET, HEAD`` (aiohttp's router).

Pacing
------
With a trace (:mod:`l3gs_opt.delivery.shaping`) the bodies of file responses are written in pieces
no larger than the shaper's burst, each after its session's bucket allows it. A session is named
by the request header ``X-L3gs-Client`` (any token up to 64 characters); ``X-L3gs-Trace-Slot: t``
on its first request starts its trace at slot ``t`` (a resumed client), and ``X-L3gs-Session-Age: s``
that many seconds ago (when the client's slot clock started). Requests without a name are
paced per TCP connection when ``shape_anonymous`` is set (the default), else not paced (a client's
side channel, e.g. the catalogue fetch of :mod:`l3gs_opt.delivery.fetch`). ``index.json`` is never
paced (the simulator, too, does not charge the manifest fetch to the trace).

A client that disconnects mid-body ends that response only (no traceback, nothing logged above
debug level).
"""

from __future__ import annotations

import asyncio
import dataclasses
import errno
import hashlib
import ipaddress
import logging
import math
import os
import re
import threading
from pathlib import Path
from typing import Optional

from aiohttp import web

from l3gs_opt.delivery.shaping import MAX_AGE_S, TraceShaper, trace_shaper
from l3gs_opt.delivery.tables import TABLES_NAME, read_tables
from l3gs_opt.errors import L3gsError
from l3gs_opt.scene.stream_index import INDEX_NAME, read_stream, verify_stream

__all__ = ["ServerError", "ByteRange", "parse_range", "make_app", "start_server", "ServerHandle", "run_server",
           "CLIENT_HEADER", "TRACE_SLOT_HEADER", "PIECE_BYTES"]

CLIENT_HEADER = "X-L3gs-Client"
TRACE_SLOT_HEADER = "X-L3gs-Trace-Slot"
#: On a session's first request: seconds since the client's slot clock started (its first request
#: reaches the server a little later), so that the server's trace slots line up with its cuts.
SESSION_AGE_HEADER = "X-L3gs-Session-Age"


def _age(value: Optional[str]) -> float:
    """A session age header as seconds in [0, MAX_AGE_S]; anything else is 0 (not an error: the
    pacing is then only a few milliseconds off)."""
    if value is None or len(value) > 16:
        return 0.0
    try:
        age = float(value)
    except ValueError:
        return 0.0
    return age if math.isfinite(age) and 0.0 <= age <= MAX_AGE_S else 0.0
#: Largest piece written at once without pacing (bytes): big enough for speed, small enough for memory.
PIECE_BYTES = 256 * 1024
_CLIENT_NAME = re.compile(r"^[A-Za-z0-9._:-]{1,64}$")
# One range of the bytes unit (RFC 9110 14.1.1); numbers capped at 19 digits (beyond any file size).
_RANGE = re.compile(r"^\s*bytes\s*=\s*(\d{0,19})\s*-\s*(\d{0,19})\s*$", re.IGNORECASE)
_log = logging.getLogger(__name__)
_FILES = web.AppKey("files", object)
_SHAPER = web.AppKey("shaper", object)
_ANONYMOUS = web.AppKey("shape_anonymous", bool)


class ServerError(L3gsError, ValueError):
    """A bad server option (folder, host, port, trace); names the field."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(f"{field}: {message}")


@dataclasses.dataclass(frozen=True)
class ByteRange:
    """Bytes ``[start, end)`` of a representation of ``size`` bytes (``end`` exclusive)."""

    start: int
    end: int
    size: int

    @property
    def content_range(self) -> str:
        return f"bytes {self.start}-{self.end - 1}/{self.size}"


def parse_range(header: Optional[str], size: int) -> "ByteRange | str | None":
    """The range a ``Range`` header asks of a ``size``-byte file.

    Returns
    -------
    ByteRange
        One satisfiable range (clipped to the file).
    "unsatisfiable"
        One well-formed range that selects no byte (answer 416).
    None
        No header, a header that does not parse, or several ranges: answer with the whole file.
    """
    if header is None or "," in header:
        return None
    m = _RANGE.match(header)
    if m is None:
        return None
    first, last = m.group(1), m.group(2)
    if first == "" and last == "":
        return None
    if first == "":                       # suffix: the last n bytes
        n = int(last)
        if n == 0 or size == 0:
            return "unsatisfiable"
        return ByteRange(max(0, size - n), size, size)
    a = int(first)
    if last != "" and int(last) < a:       # invalid syntax (RFC 9110 14.1.1): ignore the field
        return None
    if a >= size:
        return "unsatisfiable"
    b = size - 1 if last == "" else min(int(last), size - 1)
    return ByteRange(a, b + 1, size)


def _etag_matches(header: str, etag: str) -> bool:
    """``If-None-Match`` / ``If-Range`` list against ``etag`` (weak comparison: ``W/`` ignored)."""
    if header.strip() == "*":
        return True
    for tag in header.split(","):
        tag = tag.strip()
        if tag.startswith("W/"):
            tag = tag[2:]
        if tag == etag:
            return True
    return False


class _Files:
    """The allow-list (URL path -> resolved file) and the ETag cache."""

    def __init__(self, folder: Path, verify: bool = True):
        folder = Path(folder)
        if folder.name == INDEX_NAME and folder.is_file():   # the index itself, as read_stream takes it
            folder = folder.parent
        if not folder.is_dir():
            raise ServerError("folder", f"{folder} is not a folder (expected a stream export holding {INDEX_NAME})")
        index = read_stream(folder)
        if verify:
            verify_stream(index)
        root = folder.resolve()
        self.root = root
        self.paths = {INDEX_NAME: root / INDEX_NAME}
        for name in index.filenames:
            self.paths[name] = (root / name).resolve()
        #: Files served unpaced: the index and the utility tables.
        self.metadata = {INDEX_NAME}
        if (root / TABLES_NAME).is_file():
            self.paths[TABLES_NAME] = root / TABLES_NAME
            self.metadata.add(TABLES_NAME)
            for i, entry in enumerate(read_tables(root)):
                path = (root / entry["file"]).resolve()
                if not path.is_relative_to(root):
                    raise ServerError("tables", f"[{i}] {entry['file']} resolves outside {root}")
                self.paths[entry["file"]] = path
                self.metadata.add(entry["file"])
        self._etags: dict[tuple, str] = {}

    def etag(self, key: tuple) -> Optional[str]:
        return self._etags.get(key)

    def hash_file(self, key: tuple, path: Path) -> str:
        h = hashlib.sha256()
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        tag = f'"sha256:{h.hexdigest()[:32]}"'
        if len(self._etags) > 4 * len(self.paths):   # rewritten files leave stale keys: keep it bounded
            self._etags.clear()
        self._etags[key] = tag
        return tag


def make_app(folder, *, trace=None, shape_anonymous: bool = True, verify: bool = True) -> web.Application:
    """The aiohttp application serving the stream export in ``folder`` (see the module docstring).

    Parameters
    ----------
    folder : path
        A stream export (holding ``index.json``).
    trace : trace name or file, sequence of int (bytes per 1 s slot), TraceShaper or None
        Pace file bodies to this trace per session (None: as fast as the host allows).
    shape_anonymous : bool
        Pace requests without an ``X-L3gs-Client`` name per connection (else they are not paced).
    verify : bool
        Hash every chunk against the index first (reads the whole export once; off: serve as is).

    Raises
    ------
    StreamError
        ``folder`` holds no valid stream index, or (``verify``) a chunk whose bytes are not the index's.
    ServerError, ShapingError
        ``folder`` is not a folder; a bad trace.
    """
    for name, flag in (("shape_anonymous", shape_anonymous), ("verify", verify)):
        if not isinstance(flag, bool):
            raise ServerError(name, f"{flag!r}: must be True or False")
    files = _Files(Path(folder), verify)
    shaper = None if trace is None else trace_shaper(trace)
    app = web.Application()
    app[_FILES], app[_SHAPER], app[_ANONYMOUS] = files, shaper, bool(shape_anonymous)
    app.router.add_get("/{tail:.*}", _handle)
    return app


def _bucket(request: web.Request, shaper: Optional[TraceShaper], anonymous: bool):
    if shaper is None:
        return None
    name = request.headers.get(CLIENT_HEADER)
    start = request.headers.get(TRACE_SLOT_HEADER, "0")
    start_slot = int(start) if start.isdigit() and len(start) <= 9 else 0
    if name is not None and _CLIENT_NAME.match(name):
        return shaper.session(("client", name), start_slot=start_slot,
                              age_s=_age(request.headers.get(SESSION_AGE_HEADER)))
    if not anonymous:
        return None
    transport = request.transport
    return shaper.session(("connection", id(transport)), start_slot=start_slot) if transport is not None else None


async def _handle(request: web.Request) -> web.StreamResponse:
    files: _Files = request.app[_FILES]
    name = request.match_info.get("tail", "")
    path = files.paths.get(name)
    if path is None:
        raise web.HTTPNotFound(text="not found\n")
    try:
        fh = open(path, "rb")
    except OSError:
        raise web.HTTPNotFound(text="not found\n") from None
    try:
        st = os.fstat(fh.fileno())
        key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
        etag = files.etag(key) or await asyncio.to_thread(files.hash_file, key, path)
        size = st.st_size
        headers = {"ETag": etag, "Accept-Ranges": "bytes",
                   "Content-Type": "application/json" if name == INDEX_NAME else "application/octet-stream"}
        inm = request.headers.get("If-None-Match")
        if inm is not None and _etag_matches(inm, etag):
            return web.Response(status=304, headers={"ETag": etag})
        rng = None
        if request.method == "GET":
            rng = parse_range(request.headers.get("Range"), size)
            if_range = request.headers.get("If-Range")
            if rng is not None and if_range is not None and if_range.strip() != etag:
                rng = None   # strong comparison (RFC 9110 13.1.5); dates never match: none are served
        if rng == "unsatisfiable":
            return web.Response(status=416, headers={**headers, "Content-Range": f"bytes */{size}"})
        start, end = (rng.start, rng.end) if rng is not None else (0, size)
        resp = web.StreamResponse(status=206 if rng is not None else 200, headers=headers)
        if rng is not None:
            resp.headers["Content-Range"] = rng.content_range
        resp.content_length = end - start
        await resp.prepare(request)
        if request.method == "HEAD":
            return resp
        bucket = None if name in files.metadata else \
            _bucket(request, request.app[_SHAPER], request.app[_ANONYMOUS])
        fh.seek(start)
        left = end - start
        try:
            while left > 0:
                piece = PIECE_BYTES if bucket is None else min(PIECE_BYTES, bucket.piece_bytes())
                # A blocking read on the loop: pieces are at most PIECE_BYTES of a local, usually cached file.
                data = fh.read(min(piece, left))
                if not data:
                    # The file shrank under us: close the connection, so the client sees a short body.
                    resp.force_close()
                    _log.warning("%s shrank while being sent: connection closed after %d of %d bytes", name,
                                 end - start - left, end - start)
                    return resp
                if bucket is not None:
                    await bucket.acquire(len(data))
                await resp.write(data)
                left -= len(data)
            await resp.write_eof()
        except (ConnectionError, asyncio.CancelledError) as exc:
            # The client went away mid-body: nothing to answer; other responses go on.
            _log.debug("client left during %s: %r", name, exc)
            if isinstance(exc, asyncio.CancelledError):
                raise
        return resp
    finally:
        fh.close()


@dataclasses.dataclass
class ServerHandle:
    """A server running in a background thread: ``url`` (``http://host:port``), ``stop()``."""

    url: str
    host: str
    port: int
    _loop: asyncio.AbstractEventLoop
    _thread: threading.Thread
    _runner: web.AppRunner

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop serving and join the thread (idempotent)."""
        if not self._thread.is_alive():
            return
        fut = asyncio.run_coroutine_threadsafe(self._runner.cleanup(), self._loop)
        try:
            fut.result(timeout_s)
        finally:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout_s)

    def __enter__(self) -> "ServerHandle":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _check_bind(host: str, port: int) -> None:
    if not isinstance(host, str) or not host:
        raise ServerError("host", f"{host!r}: must be a host name or address")
    # The server has no authentication and no TLS: it is for local viewing and tests, never a network.
    if not _is_loopback(host):
        raise ServerError("host", f"{host!r}: only a loopback address is allowed (127.0.0.0/8, ::1 or localhost): "
                                  "the server is for local viewing and tests")
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise ServerError("port", f"{port!r}: must be a port number in [0, 65535] (0: any free port)")


def _bind_error(exc: BaseException, host: str, port: int) -> BaseException:
    """A failure to listen as one line naming ``port`` (aiohttp words it "error while attempting to
    bind on address ..."); any other exception as it is."""
    if isinstance(exc, OSError) and exc.errno in (errno.EADDRINUSE, errno.EADDRNOTAVAIL, errno.EACCES):
        return ServerError("port", f"{port}: cannot listen on {host}: {os.strerror(exc.errno).lower()}")
    return exc


def start_server(folder, host: str = "127.0.0.1", port: int = 0, trace=None, *,
                 shape_anonymous: bool = True, verify: bool = True, timeout_s: float = 10.0) -> ServerHandle:
    """Serve ``folder`` (see :func:`make_app`) from a background thread; returns once it listens.

    Parameters
    ----------
    folder : path
        A stream export.
    host : str
        Loopback address to bind (127.0.0.0/8, ``::1`` or ``localhost``; anything else is refused).
    port : int
        Port (0: a free one; read it from ``handle.port``).
    trace, shape_anonymous, verify : see :func:`make_app`
    timeout_s : float
        Seconds to wait for the server to listen.

    Raises
    ------
    StreamError, ServerError, ShapingError
        Bad folder or trace (raised here, before the thread starts); ``ServerError`` naming ``port`` if the
        address is taken.
    """
    _check_bind(host, port)
    app = make_app(folder, trace=trace, shape_anonymous=shape_anonymous, verify=verify)
    loop = asyncio.new_event_loop()
    # Responses still being paced when stop() is called are cut after a second, not the default minute.
    runner = web.AppRunner(app, access_log=None, handle_signals=False, shutdown_timeout=1.0)
    ready: dict = {}
    started = threading.Event()

    def main() -> None:
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(runner.setup())
            site = web.TCPSite(runner, host, port)
            loop.run_until_complete(site.start())
            ready["port"] = site._server.sockets[0].getsockname()[1]
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            ready["error"] = exc
            started.set()
            loop.close()
            return
        started.set()
        try:
            loop.run_forever()
        finally:
            loop.close()

    thread = threading.Thread(target=main, name=f"l3gs-serve-{Path(folder).name}", daemon=True)
    thread.start()
    if not started.wait(timeout_s):
        raise ServerError("port", f"the server did not start listening within {timeout_s} s")
    if "error" in ready:
        raise _bind_error(ready["error"], host, port)
    p = ready["port"]
    shown = f"[{host}]" if ":" in host else host
    return ServerHandle(url=f"http://{shown}:{p}", host=host, port=p, _loop=loop, _thread=thread, _runner=runner)


def run_server(folder, host: str = "127.0.0.1", port: int = 8000, trace=None, *,
               shape_anonymous: bool = True, verify: bool = True, announce: Optional[str] = None) -> None:
    """Serve ``folder`` in the foreground until interrupted (the ``serve`` command); ``announce`` is
    printed once the server listens (not before its checks: a refused folder or address prints
    only its error)."""
    _check_bind(host, port)
    app = make_app(folder, trace=trace, shape_anonymous=shape_anonymous, verify=verify)
    try:
        web.run_app(app, host=host, port=port, access_log=None,
                    print=None if announce is None else (lambda _aiohttp_line: print(announce, flush=True)))
    except OSError as exc:
        raise _bind_error(exc, host, port) from exc
