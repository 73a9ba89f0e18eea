"""A free localhost TCP port for a server the tests start, and starting it there although another process may
take the port between the choice and the server's bind (several test runs share a machine). Standard library only."""

from __future__ import annotations

import socket
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

#: Ports tried before giving up: a port is taken in that gap rarely, twice running very rarely.
ATTEMPTS = 5


class PortTaken(RuntimeError):
    """The server could not bind its port: another process has it."""


def free_port() -> int:
    """A localhost port nobody listens on now (the system's choice, released at once)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def on_a_free_port(start: Callable[[int], T]) -> T:
    """``start(port)`` on a free port; on another one when it raises :class:`PortTaken`."""
    for _ in range(ATTEMPTS - 1):
        try:
            return start(free_port())
        except PortTaken:
            continue
    return start(free_port())
