"""Errors that the CLI reports as one clear line instead of a traceback, and the warnings
a use case says on its way (:class:`Warnings`)."""

from __future__ import annotations

from collections.abc import Callable, Iterable


class UserError(Exception):
    """Bad file, bad argument or missing device: the user can fix it.

    The CLI prints ``tpods: error: <message>`` and exits with status 2.
    """


class DeviceError(UserError):
    """A device did not answer, answered nonsense or refused a command."""


class Warnings(list):
    """A use case's warnings (one line each, in order), each also handed to ``on_warning``
    as it is added (the CLI prints it as ``tpods: warning: ...``), so that a warning said
    before a failure reaches the user with the error. Without ``on_warning`` a plain list."""

    def __init__(self, on_warning: Callable[[str], object] | None = None,
                 items: Iterable[str] = ()) -> None:
        super().__init__()
        self.on_warning = on_warning
        self.extend(items)

    def append(self, w: str) -> None:
        super().append(w)
        if self.on_warning is not None:
            self.on_warning(w)

    def extend(self, ws: Iterable[str]) -> None:
        for w in ws:
            self.append(w)

    def __iadd__(self, ws: Iterable[str]) -> Warnings:
        self.extend(ws)
        return self
