"""docs/zenoh.md says what runs: its payload examples are real payloads (its TLS and
access-control blocks are run by ``test_tls_acl.py``)."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator

import pytest
from procs import REPO, Child

from baromap import jsonmsg
from baromap.live.keys import Channel
from baromap.live.payloads import decode

DOC = REPO / "docs" / "zenoh.md"
CHANNEL_OF_SCHEMA = {
    "baromap.FloorEvent": Channel.EVENT,
    "baromap.RideEvent": Channel.RIDE,
    "baromap.FloorState": Channel.STATE,
    "baromap.PressureSample": Channel.PRESSURE,
    "baromap.DeviceHealth": Channel.HEALTH,
}


def blocks(language: str) -> dict[str, str]:
    """The doc's ``language`` code blocks by their first line (a comment naming them)."""
    text = DOC.read_text()
    named = {}
    for body in re.findall(rf"```{language}\n(.*?)```", text, flags=re.S):
        first = body.partition("\n")[0]
        named[first.lstrip("/# ").strip()] = body
    return named


def test_the_payload_examples_are_what_the_code_publishes() -> None:
    text = DOC.read_text()
    section = text.split("<!-- generated examples: begin -->")[1].split("<!-- generated")[0]
    examples = re.findall(
        r"`(baromap/[^`]+)` \(encoding `application/json;([^`]+)`\):\n\n```json\n(.*?)```",
        section,
        flags=re.S,
    )
    schemas = {schema for _key, schema, _payload in examples}
    assert schemas == set(CHANNEL_OF_SCHEMA), "an example per published type"
    for key, schema, payload in examples:
        channel = CHANNEL_OF_SCHEMA[schema]
        assert key.endswith("/" + channel.value)
        message = decode(channel, payload.encode())
        assert json.loads(jsonmsg.dumps(message)) == json.loads(payload)


@pytest.fixture
def children() -> Iterator[list[Child]]:
    started: list[Child] = []
    yield started
    for child in reversed(started):
        child.close(interrupt=child.name.startswith("watch"))
