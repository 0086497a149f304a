"""docs/zenoh.md says what runs: its payload examples are real payloads, and its TLS and
access-control blocks, run as written on loopback, let a robot reach a dashboard through a
router and keep an impostor out."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from procs import REPO, Child, endpoint, free_port

from baromap import jsonmsg
from baromap.live.keys import Channel
from baromap.live.payloads import decode
from baromap.live.settings import LiveSettings

DOC = REPO / "docs" / "zenoh.md"
CHANNEL_OF_SCHEMA = {
    "baromap.FloorEvent": Channel.EVENT,
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


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl not installed")
def test_the_building_network_blocks_run_as_written(tmp_path: Path, children: list[Child]) -> None:
    certs = tmp_path / "certs"
    certs.mkdir()
    sh = blocks("sh")
    subprocess.run(
        ["bash", "-e", "-c", sh["make-certs"]], cwd=certs, check=True, capture_output=True
    )
    port = free_port()
    files = {}
    for name, body in blocks("json5").items():
        local = body.replace("/etc/baromap/zenoh/", f"{certs}/")
        local = local.replace("tls/0.0.0.0:7447", endpoint(port).replace("tcp/", "tls/"))
        files[name] = tmp_path / name
        files[name].write_text(local)
    table: dict[str, Any] = tomllib.loads(blocks("toml")["baromapd.toml (pioneer-1)"])
    zenoh_table = table["zenoh"]
    assert zenoh_table["connect"] == ["tls/router.building.example:7447"]
    zenoh_table["connect"] = [f"tls/127.0.0.1:{port}"]
    zenoh_table["config_file"] = str(files["robot.json5"])
    LiveSettings.from_table(zenoh_table)  # the table is valid as the daemon reads it
    robot_toml = tmp_path / "baromapd.toml"
    robot_toml.write_text(
        "[zenoh]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in zenoh_table.items())
    )

    router = Child.node("router", ["router", "--config", str(files["router.json5"])], tmp_path)
    children.append(router)
    router.expect(lambda line: "ready" in line, 30, "router ready")
    robots = {}
    for robot, seed in (("pioneer-1", 1), ("pioneer-2", 2)):  # pioneer-2 holds 1's certificate
        args = ["robot", robot, "--table", str(robot_toml), "--seed", str(seed)]
        robots[robot] = Child.node(robot, args, tmp_path)
        children.append(robots[robot])
    for robot, child in robots.items():
        child.expect(lambda line, r=robot: line.get("ready") == r, 60, "robot ready")
    watch = Child.watch(
        "watch",
        [
            "--connect",
            f"tls/127.0.0.1:{port}",
            "--zenoh-config",
            str(files["dashboard.json5"]),
            "--states",
        ],
        tmp_path,
    )
    children.append(watch)
    answered = watch.expect(lambda line: line.get("report") == "answered", 30, "answers")
    assert answered["robots"] == ["pioneer-1"]
    for child in robots.values():
        child.send("go")
    done = {
        robot: child.expect(lambda line, r=robot: line.get("done") == r, 120, "run done")
        for robot, child in robots.items()
    }
    assert done["pioneer-2"]["events"], "the impostor decided events it could have published"
    last = done["pioneer-1"]["events"][-1]
    watch.expect(
        lambda line: line.get("report") == "event" and line["event"] == last, 30, "last event"
    )
    watch.collect(1.0)  # anything pioneer-2 got through would be here by now
    events = [line["event"] for line in watch.lines if line.get("report") == "event"]
    assert events == done["pioneer-1"]["events"]
    assert all(line.get("robot") != "pioneer-2" for line in watch.lines)
