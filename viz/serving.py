"""Serving the browser viewer: where it listens, what it shows first, and its life until Ctrl-C.

:class:`ViewerOptions` (host, port, first probe, replay rate) become ``fluidgs view``'s options; :func:`check_address`
finds the port with a plain socket before the viser server starts, so that a bad address or a full range is a clear
error at once; :func:`serve` announces the URL and serves until Ctrl-C or SIGTERM, then stops the server cleanly.

Example:
    >>> port = check_address("127.0.0.1", 0)  # doctest: +SKIP
"""

from __future__ import annotations

import errno
import ipaddress
import logging
import signal
import socket
import threading
from dataclasses import dataclass
from typing import Protocol

log = logging.getLogger("viz.viewer")  # the viewer's one logger, whichever of its modules writes the line

INSTALL_HINT = "`fluidgs view` needs viser: pip install -e .[view] (or pip install 'viser>=1.0')"


@dataclass(frozen=True)
class ViewerOptions:
    """Where to serve and what to show first.

    Attributes:
        host: the address to bind (127.0.0.1: this machine only; 0.0.0.0: every interface).
        port: the port (0: any free one); a port in use moves to the next free one, logged.
        probe: the probe whose fluid is replayed (None: the first recorded one, else the first probe).
        fps: replay frames per second.
    """

    host: str = "127.0.0.1"
    port: int = 8080
    probe: str | None = None
    fps: float = 10.0

    def __post_init__(self) -> None:
        if isinstance(self.port, bool) or not isinstance(self.port, int) or not 0 <= self.port <= 65535:
            raise ValueError(f"--port must be an integer in 0..65535 (0: any free port), got {self.port!r}")
        if not isinstance(self.host, str) or not self.host.strip():
            raise ValueError(f"--host must be an address such as 127.0.0.1, got {self.host!r}")
        if not self.fps > 0:
            raise ValueError(f"--fps must be > 0 frames per second, got {self.fps}")


def import_viser():
    """viser, or a ValueError saying how to install it."""
    try:
        import viser  # noqa: PLC0415 - the optional 'view' extra
    except ImportError as exc:
        raise ValueError(f"{INSTALL_HINT} ({exc})") from None
    return viser


PORT_TRIES = 64  # a port in use moves up to this many ports on


def check_address(host: str, port: int) -> int:
    """The port to serve on: ``port`` when it is free on ``host``, else the next free one of :data:`PORT_TRIES`
    (logged), or 0 for 0 (any free port). Tried with a plain socket before the server starts, so that a bad address
    or a full range is a clear error at once (viser would wait forever or print a traceback).

    Raises:
        ValueError: ``host`` does not resolve or is not an address of this machine; no port is free; a port below
            1024 needs privileges.
    """
    try:
        infos = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise ValueError(
            f"--host {host}: not a name or address this machine can resolve ({exc}); use 127.0.0.1, "
            "0.0.0.0 or an address of this machine"
        ) from None
    family, _, _, _, addr = infos[0]
    last = 65535 if port == 0 else min(port + PORT_TRIES - 1, 65535)
    for candidate in range(port, last + 1):
        with socket.socket(family, socket.SOCK_STREAM) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as a server binds
            try:
                sock.bind((addr[0], candidate, *addr[2:]))
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE:
                    continue
                if exc.errno == errno.EADDRNOTAVAIL:
                    raise ValueError(
                        f"--host {host} is not an address of this machine; use 127.0.0.1 (this machine "
                        "only), 0.0.0.0 (every interface) or one of its own addresses"
                    ) from None
                if exc.errno == errno.EACCES:
                    raise ValueError(
                        f"--port {candidate} needs administrator privileges (ports below 1024); choose "
                        "a port from 1024 up, or 0 for any free port"
                    ) from None
                raise ValueError(
                    f"--host {host} --port {candidate}: cannot serve there ({exc.strerror}); choose "
                    "another --host or --port"
                ) from None
        if candidate != port and port != 0:
            log.warning("port %d is in use; serving on port %d instead", port, candidate)
        return 0 if port == 0 else candidate
    raise ValueError(
        f"--port {port} is in use, and so is every port up to {last}; choose another --port (0: any free port)"
    )


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class Served(Protocol):
    """What :func:`serve` needs of a page (:class:`viz.viewer.FluidViewer` is one): its URL, a wait until it is
    stopped, and a clean stop."""

    @property
    def url(self) -> str: ...

    def wait(self) -> None: ...

    def close(self) -> None: ...


def serve(viewer: Served, announce=log.info) -> int:
    """Announce the URL (``announce(line)``; `fluidgs view` prints it), serve until Ctrl-C (or SIGTERM), stop
    cleanly; returns 0."""

    def on_term(signum, frame):
        raise KeyboardInterrupt

    main = threading.current_thread() is threading.main_thread()
    previous = {s: signal.signal(s, on_term) for s in (signal.SIGTERM, signal.SIGHUP)} if main else {}
    try:  # the URL is announced inside: a Ctrl-C right after it (on a loaded machine) also stops cleanly
        announce(f"fluidgs view: {viewer.url} (Ctrl-C stops)")
        viewer.wait()
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
        for s, handler in previous.items():
            signal.signal(s, handler)
    log.info("viewer stopped")
    return 0
