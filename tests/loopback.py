"""Network tests stay on loopback: a free port there, and a guard that fails a test the moment
it would bind anything else (so a test of "refuses 0.0.0.0" never binds it)."""

from __future__ import annotations

import socket

import pytest


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def no_remote_bind(monkeypatch: pytest.MonkeyPatch) -> list[object]:
    """Every bind in the test goes through here and is recorded; a non-loopback one fails the
    test before it reaches the kernel."""
    binds: list[object] = []
    real_bind = socket.socket.bind

    def bind(self: socket.socket, address: object) -> None:
        binds.append(address)
        host = address[0] if isinstance(address, tuple) else ""
        assert host in ("127.0.0.1", "localhost"), f"the test tried to bind {address!r}"
        real_bind(self, address)  # type: ignore[arg-type]

    monkeypatch.setattr(socket.socket, "bind", bind)
    return binds
