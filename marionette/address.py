"""The address a local server (``marionette app``, ``marionette view``) listens on, checked before it starts.

Unchecked, a port out of range fails deep in the socket library with a
traceback, a host that is not this machine's makes viser wait for ever, and
viser moves from a port in use to the next free one without a word.
"""

from __future__ import annotations

import errno
import socket

from .errors import InputError

__all__ = ["check_address", "port_in_use"]


def port_in_use(port: int) -> InputError:
    """The error for a port another program listens on."""
    return InputError(f"port {port} is in use; --port 0 picks a free one")


def check_address(host: str, port: int) -> None:
    """Raise InputError unless ``host`` is an address of this machine and ``port`` (0: any free one) is free on it."""
    if not 0 <= port <= 65535:
        raise InputError(f"port must be in 0..65535 (0: any free port), got {port}")
    try:
        family = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM)[0][0]
        with socket.socket(family, socket.SOCK_STREAM) as s:
            s.bind((host, 0))
    except (OSError, UnicodeError) as e:
        raise InputError(f"cannot listen on host {host!r} ({getattr(e, 'strerror', None) or e})") from None
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the servers do: a port in TIME_WAIT is free
        try:
            s.bind((host, port))
        except OSError as e:
            if e.errno == errno.EADDRINUSE:
                raise port_in_use(port) from None
            raise InputError(f"cannot listen on {host}:{port} ({e.strerror or e})") from None
