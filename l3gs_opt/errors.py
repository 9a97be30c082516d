"""The library's exceptions: one small tree, all ``ValueError`` subclasses where input is at fault."""

from __future__ import annotations

__all__ = ["L3gsError", "InstanceError", "SolveError", "BackendUnavailableError", "os_error_reason"]


class L3gsError(Exception):
    """Base class of every error raised by l3gs-opt on purpose."""


class InstanceError(L3gsError, ValueError):
    """An instance (or instance file) breaks the ``l3gs-opt/instance@1`` contract.

    Attributes
    ----------
    field : str
        The field at fault (``"cost"``, ``"utility"``, ``"options.budget"``, ...).
    index : tuple of int or None
        The index inside that field, when the fault is one entry.
    """

    def __init__(self, field: str, message: str, index: tuple[int, ...] | None = None):
        self.field = field
        self.index = tuple(int(i) for i in index) if index is not None else None
        where = field + "".join(f"[{i}]" for i in self.index or ())
        # "cost[1][1] = 0: must be ..." reads better than "cost[1][1]: = 0: ..."
        sep = " " if message.startswith("= ") else ": "
        super().__init__(f"{where}{sep}{message}")


class SolveError(L3gsError, ValueError):
    """A solve request is malformed (unknown method, option that does not apply, bad slot)."""


class BackendUnavailableError(L3gsError, RuntimeError):
    """The chosen backend's library is not installed."""


def os_error_reason(exc: OSError) -> str:
    """Why a file operation failed, in words: the system's text, except that ``File exists`` from
    ``mkdir(exist_ok=True)``, its only source here, means a file stands where a folder is needed."""
    return "a file where a folder is needed" if isinstance(exc, FileExistsError) else exc.strerror or str(exc)
