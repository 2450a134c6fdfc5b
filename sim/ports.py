"""Loopback port allocation for the harness, the benchmarks and the tests (one implementation for all)."""
from __future__ import annotations

import contextlib
import socket


def free_ports(kind: int, count: int) -> list[int]:
    """`count` distinct loopback ports of socket type `kind` (socket.SOCK_STREAM: TCP, socket.SOCK_DGRAM: UDP)
    that were free a moment ago: the kernel's picks, all held bound until all are picked, so that two calls'
    closed sockets cannot hand out the same port twice (another process may still take one before the caller
    binds it)."""
    with contextlib.ExitStack() as stack:
        ports = []
        for _ in range(count):
            sock = stack.enter_context(socket.socket(socket.AF_INET, kind))
            sock.bind(("127.0.0.1", 0))
            ports.append(sock.getsockname()[1])
        return ports


def free_port(kind: int) -> int:
    """A loopback port of socket type `kind` that was free a moment ago (free_ports for several at once)."""
    return free_ports(kind, 1)[0]


def free_tcp_port() -> int:
    """A loopback TCP port that was free a moment ago."""
    return free_port(socket.SOCK_STREAM)


def free_udp_port() -> int:
    """A loopback UDP port that was free a moment ago."""
    return free_port(socket.SOCK_DGRAM)


def free_tcp_ports(count: int) -> list[int]:
    """`count` distinct loopback TCP ports (free_ports)."""
    return free_ports(socket.SOCK_STREAM, count)


def free_udp_ports(count: int) -> list[int]:
    """`count` distinct loopback UDP ports (free_ports)."""
    return free_ports(socket.SOCK_DGRAM, count)
