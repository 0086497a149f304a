"""The live view's tests: the Foxglove SDK's runtime is made once, before the leak checks.

The SDK runs its WebSocket servers on one Tokio runtime per process, made at the first
server and kept (its epoll, eventfd and wake-up sockets): started here once, it is not
taken for a leak of the first test that starts a server.
"""

from __future__ import annotations

from collections.abc import Iterator

import foxglove
import pytest


@pytest.fixture(scope="session", autouse=True)
def sdk_runtime() -> Iterator[None]:
    server = foxglove.start_server(host="127.0.0.1", port=0, context=foxglove.Context())
    server.stop()
    yield
