"""Reading user files within limits: regular files only, sizes and claimed shapes checked before
anything is allocated, JSON without duplicate keys or deep nesting.

Every reader of a user file (instances, item instances, traces, pose logs, cameras, scenes,
bundles) goes through these checks, so that a FIFO, ``/dev/zero``, a zip bomb or an NPZ header
claiming 10^12 entries is one named error instead of a hang or a ``MemoryError``.

Each function takes ``error(field, message) -> Exception``: the caller's own error type, so the
message names the caller's field (``file``, ``cameras``, ...) and the CLI prints it as one line.
The limits are module constants (documented in the README's "Bad input" section); they are far
above any file this project writes.
"""

from __future__ import annotations

import json
import os
import stat
import zipfile
import zlib
from pathlib import Path
from typing import Any, Callable

import numpy as np

from l3gs_opt.errors import L3gsError

__all__ = ["MAX_TEXT_BYTES", "MAX_JSON_DEPTH", "MAX_JSON_INT_DIGITS", "MAX_NPZ_BYTES", "MAX_BINARY_BYTES",
           "ErrorFactory", "check_regular_file", "read_text", "read_bytes", "parse_json", "read_json", "load_npz",
           "key_name"]

#: Largest JSON or text file read (bytes). A JSON instance this size already takes ~10x that in
#: Python objects while it is parsed; larger problems belong in NPZ.
MAX_TEXT_BYTES = 256 * 2**20
#: Deepest nesting of JSON arrays/objects accepted. Instances need 3 levels inside the top object;
#: free-form ``meta`` gets the rest. Deeper input would reach Python's recursion limit later on.
MAX_JSON_DEPTH = 64
#: Most digits of one JSON integer literal. Python refuses to convert longer ones (its own
#: ``sys.get_int_max_str_digits()`` default) with a ValueError that is not a decoding error; every
#: integer field is checked far below this (bytes: at most ``2**53``, 16 digits).
MAX_JSON_INT_DIGITS = 4300
#: Largest total of uncompressed NPZ members (bytes), checked against the zip directory and each
#: member's ``.npy`` header before anything is decompressed.
MAX_NPZ_BYTES = 4 * 2**30
#: Largest binary file (PLY, COLMAP ``.bin``) read whole (bytes).
MAX_BINARY_BYTES = 8 * 2**30

ErrorFactory = Callable[[str, str], Exception]


def check_regular_file(path: str | os.PathLike[str], error: ErrorFactory, *, field: str = "file",
                       max_bytes: int | None = None) -> Path:
    """``path`` as a :class:`Path` if it is an existing regular file of at most ``max_bytes`` bytes.

    A FIFO, socket or device (``/dev/zero``) would block or never end: refused before it is opened.
    """
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise error(field, f"{path}: no such file") from None
    except OSError as exc:
        raise error(field, f"{path}: cannot be read ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(field, f"{path}: is a folder, expected a file")
    if not stat.S_ISREG(st.st_mode):
        raise error(field, f"{path}: not a regular file (a FIFO, socket or device is refused)")
    if max_bytes is not None and st.st_size > max_bytes:
        raise error(field, f"{path}: {st.st_size:,} bytes, more than the limit of {max_bytes:,} bytes")
    return path


def read_bytes(path: str | os.PathLike[str], error: ErrorFactory, *, field: str = "file",
               max_bytes: int = MAX_BINARY_BYTES) -> bytes:
    """The whole file, refused when it is not a regular file or exceeds ``max_bytes``."""
    path = check_regular_file(path, error, field=field, max_bytes=max_bytes)
    try:
        with open(path, "rb") as fh:
            data = fh.read(max_bytes + 1)
    except OSError as exc:
        raise error(field, f"{path}: cannot be read ({exc.strerror or exc})") from None
    if len(data) > max_bytes:  # grew since the stat
        raise error(field, f"{path}: more than the limit of {max_bytes:,} bytes")
    return data


def read_text(path: str | os.PathLike[str], error: ErrorFactory, *, field: str = "file",
              max_bytes: int = MAX_TEXT_BYTES, errors: str = "strict") -> str:
    """The file decoded as UTF-8 (``errors`` as for :meth:`bytes.decode`)."""
    data = read_bytes(path, error, field=field, max_bytes=max_bytes)
    try:
        return data.decode("utf-8", errors=errors)
    except UnicodeDecodeError as exc:
        raise error(field, f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def key_name(key: Any) -> str:
    """A key of the user's file as a field name in a message: itself when it is a short printable
    string without surrounding spaces, else its (shortened) ``repr``, so that an empty key, a
    newline or a megabyte-long key still gives one readable line."""
    text = str(key)
    if text and text.isprintable() and text.strip() == text and len(text) <= 40:
        return text
    text = repr(key)
    return text if len(text) <= 40 else text[:37] + "..."


def _depth_exceeded(value: Any, limit: int) -> bool:
    stack = [(value, 1)]
    while stack:
        v, depth = stack.pop()
        if isinstance(v, (list, dict)):
            if depth > limit:
                return True
            children = v.values() if isinstance(v, dict) else v
            stack.extend((c, depth + 1) for c in children if isinstance(c, (list, dict)))
    return False


def parse_json(text: str | bytes, error: ErrorFactory, *, field: str = "file", where: str = "",
               max_depth: int = MAX_JSON_DEPTH) -> Any:
    """Decode JSON strictly: no duplicate keys (the last would silently win), no ``NaN`` or
    ``Infinity`` literals (not JSON), no integer longer than :data:`MAX_JSON_INT_DIGITS` digits,
    nesting at most ``max_depth`` deep.

    ``where`` prefixes messages (usually the file name).
    """
    prefix = f"{where}: " if where else ""

    def pairs(items: list[tuple[str, Any]]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for key, value in items:
            if key in out:
                raise error(key_name(key), f"{prefix}duplicate key (each key may appear once)")
            out[key] = value
        return out

    def constant(name: str) -> Any:
        raise error(field, f"{prefix}{name} is not valid JSON (write numbers only)")

    def integer(digits: str) -> int:
        if len(digits.lstrip("-")) > MAX_JSON_INT_DIGITS:
            raise error(field, f"{prefix}an integer of {len(digits.lstrip('-'))} digits "
                               f"(at most {MAX_JSON_INT_DIGITS})")
        return int(digits)

    try:
        value = json.loads(text, object_pairs_hook=pairs, parse_constant=constant, parse_int=integer)
    except RecursionError:
        raise error(field, f"{prefix}nested more than {max_depth} levels deep") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise error(field, f"{prefix}not valid JSON ({exc})") from None
    if _depth_exceeded(value, max_depth):
        raise error(field, f"{prefix}nested more than {max_depth} levels deep")
    return value


def npz_text(arr: np.ndarray, error: ErrorFactory, *, field: str) -> str:
    """The text of a 0-d string array read from an NPZ member. A ``.npy`` file may hold UCS-4 code
    units above U+10FFFF, which no Python string can: numpy still makes one, and reading it back
    (``json``, ``repr``, iteration) raises ``SystemError``. Such a member is refused here."""
    codes = np.frombuffer(arr.tobytes(), dtype=np.dtype(np.uint32).newbyteorder(arr.dtype.byteorder))
    if codes.size and int(codes.max()) > 0x10FFFF:
        raise error(field, f"holds a character code {int(codes.max()):#x} above U+10FFFF (not text)")
    return str(arr)


def read_json(path: str | os.PathLike[str], error: ErrorFactory, *, field: str = "file",
              max_bytes: int = MAX_TEXT_BYTES, max_depth: int = MAX_JSON_DEPTH) -> Any:
    """Read and strictly decode a JSON file (see :func:`parse_json`)."""
    text = read_text(path, error, field=field, max_bytes=max_bytes)
    return parse_json(text, error, field=field, where=str(path), max_depth=max_depth)


def load_npz(path: str | os.PathLike[str], error: ErrorFactory, *, field: str = "file",
             max_bytes: int = MAX_NPZ_BYTES) -> dict[str, np.ndarray]:
    """Every member of an ``.npz`` file as an array, without pickles.

    Before anything is decompressed, each member must be a ``.npy`` file whose header parses,
    and the sizes the zip directory and the headers claim must stay within ``max_bytes`` in
    total: a zip bomb or a header claiming 10^12 entries is refused by name.
    """
    path = check_regular_file(path, error, field=field)
    arrays: dict[str, np.ndarray] = {}
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
            claimed = sum(info.file_size for info in infos)
            if claimed > max_bytes:
                raise error(field, f"{path}: members claim {claimed:,} bytes uncompressed, more than "
                                   f"the limit of {max_bytes:,}")
            total = 0
            for info in infos:
                if not info.filename.endswith(".npy"):
                    raise error(field, f"{path}: member {info.filename!r} is not a .npy array")
                key = info.filename[:-4]
                name = key_name(key)
                if key in arrays:   # as for JSON keys: the last one must not silently win
                    raise error(name, f"{path}: member {info.filename!r} appears twice")
                with zf.open(info) as fh:
                    try:
                        version = np.lib.format.read_magic(fh)
                        if version == (1, 0):
                            shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
                        else:
                            shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
                    except Exception as exc:  # noqa: BLE001 - numpy's header parser lets its tokenizer's
                        # errors through (SyntaxError, tokenize.TokenError, ...): all mean a damaged header
                        raise error(name, f"{path}: member {info.filename!r} has no readable .npy header "
                                          f"({type(exc).__name__}: {exc})") from None
                    if dtype.hasobject:
                        raise error(name, f"{path}: object arrays are refused (no pickles)")
                    count = 1
                    for n in shape:
                        count *= int(n)
                    total += count * dtype.itemsize
                    if total > max_bytes:
                        raise error(name, f"{path}: header claims shape {tuple(shape)} of {dtype}, more than the "
                                          f"limit of {max_bytes:,} bytes in all")
                    if count * dtype.itemsize > info.file_size:
                        raise error(name, f"{path}: header claims shape {tuple(shape)} but the member holds only "
                                          f"{info.file_size:,} bytes")
                    fh.seek(0)
                    arrays[key] = np.lib.format.read_array(fh, allow_pickle=False)
    except L3gsError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, NotImplementedError, RuntimeError, ValueError,
            EOFError, OSError) as exc:
        # zlib.error: a corrupt deflate stream; NotImplementedError: an unsupported compression
        # method; RuntimeError: an encrypted member (zipfile's own errors for a damaged file).
        raise error(field, f"{path}: not a readable NPZ file ({exc})") from None
    return arrays
