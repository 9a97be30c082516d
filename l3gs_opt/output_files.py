"""Writing result files so that no reader, crash or Ctrl-C ever leaves half of one.

Every file the toolkit writes whole (records rewritten, reports, pictures, tables, indexes, a
build's state) goes through :func:`write_atomic`: the bytes go to a hidden temporary file beside
the target, which is renamed over it (``os.replace``, atomic on one file system). A failed write
removes its temporary file, so an error leaves the old file (or none) and nothing else.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import BinaryIO, Callable, Union

__all__ = ["write_atomic"]

Content = Union[bytes, str, Callable[[BinaryIO], object]]


def write_atomic(path: str | os.PathLike[str], content: Content, *, fsync: bool = False) -> Path:
    """Replace ``path`` by ``content``: bytes, text (UTF-8) or a function writing into the open
    binary file. ``fsync``: flush to the disk before the rename (records: a power cut keeps the old
    file or the new one). Returns the path.

    Raises
    ------
    OSError
        As ``open`` and ``os.replace`` raise it (the temporary file is removed first).
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            if callable(content):
                content(fh)
            else:
                fh.write(content.encode("utf-8") if isinstance(content, str) else content)
            if fsync:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path
