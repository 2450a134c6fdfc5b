"""Loopback port allocation for the harness, the benchmarks and the tests (one implementation for all)."""
from __future__ import annotations

import socket


def free_port(kind: int) -> int:
    """A loopback port of socket type `kind` (socket.SOCK_STREAM: TCP, socket.SOCK_DGRAM: UDP) that was free a
    moment ago (the kernel's pick; another process may take it before the caller binds it)."""
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def free_tcp_port() -> int:
    """A loopback TCP port that was free a moment ago."""
    return free_port(socket.SOCK_STREAM)


def free_udp_port() -> int:
    """A loopback UDP port that was free a moment ago."""
    return free_port(socket.SOCK_DGRAM)
