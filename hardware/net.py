"""Reaching an arm controller: a bounded TCP pre-flight and one message for every way a connection fails.

The vendors' SDKs fail in their own ways when nothing answers (xarm-python-sdk raises a bare
``Exception("connect socket failed")``; ur-rtde raises ``RuntimeError``, and may wait long on an address that
drops packets). The adapters first open (and close) a TCP connection to the controller's port with a
timeout, so an unreachable controller fails within seconds, then wrap whatever the SDK raises into an
:class:`~hardware.interfaces.ArmFault` naming the address.
"""

from __future__ import annotations

import socket

from hardware.interfaces import ArmFault


def unreachable(who: str, ip: str, reason: str) -> ArmFault:
    """The one-line fault for a controller that cannot be connected to."""
    return ArmFault(f"{who} {ip}: cannot connect to the controller ({reason}); check that it is powered on and "
                    f"reachable at {ip} (network cable, this computer's address in the same subnet)")


def preflight(who: str, ip: str, port: int, timeout_s: float | None) -> None:
    """Raise :func:`unreachable` unless ``ip:port`` accepts a TCP connection within ``timeout_s`` (None: skip)."""
    if timeout_s is None:
        return
    try:
        socket.create_connection((ip, port), timeout=timeout_s).close()
    except socket.timeout:
        raise unreachable(who, ip, f"nothing answers on TCP port {port} within {timeout_s:g} s") from None
    except OSError as exc:
        raise unreachable(who, ip, f"nothing answers on TCP port {port}: {exc.strerror or exc}") from None
