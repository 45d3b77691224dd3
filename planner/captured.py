"""What one thread prints while it runs a CasADi call, kept apart from what other threads
print.

A CasADi Function whose call fails prints its name and every input through Python's
`sys.stdout` from the thread that called it. `contextlib.redirect_stdout` would swap the
process's one stream for everyone: two captures at once in two threads would leave it
pointing into one's buffer. Here, while any thread captures, `sys.stdout` and
`sys.stderr` are routers that send a capturing thread's writes into its own buffers and
every other thread's on to the streams they replaced; the last capture to end puts those
streams back.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import threading
from collections.abc import Iterator
from typing import Any, TextIO

_GUARD = threading.Lock()
"""Guards `_BUFFERS` and the installation of the routers."""
_BUFFERS: dict[int, tuple[io.StringIO, io.StringIO]] = {}
"""The (stdout, stderr) buffers of every thread that captures, by thread identifier."""


class _Router:
    """A text stream that writes a capturing thread's text into its buffer (stdout's or
    stderr's: `which`, 0 or 1) and anyone else's into the stream it replaced."""

    def __init__(self, stream: TextIO, which: int):
        self.stream, self.which = stream, which

    def write(self, text: str) -> int:
        buffers = _BUFFERS.get(threading.get_ident())
        return (self.stream if buffers is None else buffers[self.which]).write(text)

    def flush(self) -> None:
        self.stream.flush()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.stream, name)


@contextlib.contextmanager
def captured() -> Iterator[tuple[io.StringIO, io.StringIO]]:
    """The (stdout, stderr) buffers of what this thread prints inside the block; other
    threads print as before. Not nested within one thread."""
    buffers = io.StringIO(), io.StringIO()
    ident = threading.get_ident()
    with _GUARD:
        if not _BUFFERS:
            sys.stdout, sys.stderr = _Router(sys.stdout, 0), _Router(sys.stderr, 1)
        _BUFFERS[ident] = buffers
    try:
        yield buffers
    finally:
        with _GUARD:
            del _BUFFERS[ident]
            if not _BUFFERS:
                sys.stdout, sys.stderr = _restored(sys.stdout), _restored(sys.stderr)


def _restored(stream: TextIO | _Router) -> TextIO:
    """The stream a router replaced; a stream someone set meanwhile, unchanged."""
    return stream.stream if isinstance(stream, _Router) else stream


def _forked() -> None:
    """In a forked child, which has only the thread that forked: no capture is running
    (a guard another thread held stays held in a child), so the streams are the ones the
    routers replaced."""
    global _GUARD
    _GUARD = threading.Lock()
    _BUFFERS.clear()
    sys.stdout, sys.stderr = _restored(sys.stdout), _restored(sys.stderr)


os.register_at_fork(after_in_child=_forked)
