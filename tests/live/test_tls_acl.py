"""docs/zenoh.md's building network, run as written on loopback: TLS with mutual
authentication and access control at the router.

The doc's blocks (its ``make-certs`` script, the router's, a robot's and a dashboard's files)
are taken from the doc itself, so what it says is what is tested: a robot's events reach a
dashboard through the router; a robot presenting ``pioneer-1``'s certificate while publishing
as ``pioneer-2`` reaches nobody; and a client without the right certificate (none, or one
from another CA) is refused at the handshake while one with it connects.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from procs import Child, endpoint, free_port
from test_zenoh_doc import blocks

from baromap.live.session import LiveError, close_session, open_session
from baromap.live.settings import LiveSettings

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl not installed")


@pytest.fixture
def children() -> Iterator[list[Child]]:
    started: list[Child] = []
    yield started
    for child in reversed(started):
        child.close(interrupt=child.name.startswith("watch"))


def make_certs(directory: Path) -> Path:
    """The doc's certificates, made by its own script."""
    directory.mkdir()
    subprocess.run(
        ["bash", "-e", "-c", blocks("sh")["make-certs"]],
        cwd=directory,
        check=True,
        capture_output=True,
    )
    return directory


def doc_files(tmp_path: Path, certs: Path, port: int) -> dict[str, Path]:
    """The doc's JSON5 files, with the certificates' folder and the router's port of this test."""
    files = {}
    for name, body in blocks("json5").items():
        local = body.replace("/etc/baromap/zenoh/", f"{certs}/")
        local = local.replace("tls/0.0.0.0:7447", endpoint(port).replace("tcp/", "tls/"))
        files[name] = tmp_path / name
        files[name].write_text(local)
    return files


def _client_file(tmp_path: Path, name: str, tls: dict[str, Any]) -> Path:
    path = tmp_path / f"{name}.json5"
    path.write_text(json.dumps({"transport": {"link": {"tls": tls}}}))
    return path


def test_a_client_without_the_right_certificate_is_refused(
    tmp_path: Path, children: list[Child]
) -> None:
    certs = make_certs(tmp_path / "certs")
    port = free_port()
    files = doc_files(tmp_path, certs, port)
    router = Child.node("router", ["router", "--config", str(files["router.json5"])], tmp_path)
    children.append(router)
    router.expect(lambda line: "ready" in line, 30, "router ready")
    connect = (f"tls/127.0.0.1:{port}",)

    def client(config_file: Path) -> LiveSettings:
        return LiveSettings.from_table(
            {"mode": "client", "connect": list(connect), "config_file": str(config_file)}
        )

    # The dashboard's own file (the CA's certificate): it connects.
    session = open_session(client(files["dashboard.json5"]))
    close_session(session)
    # Trusting the router, but showing no certificate: mutual TLS refuses it.
    anonymous = _client_file(tmp_path, "anonymous", {"root_ca_certificate": str(certs / "ca.pem")})
    with pytest.raises(LiveError):
        open_session(client(anonymous))
    # A certificate, with the name of a node the router knows, from another CA.
    other = tmp_path / "other"
    make_certs(other)
    forged = _client_file(
        tmp_path,
        "forged",
        {
            "root_ca_certificate": str(certs / "ca.pem"),
            "connect_private_key": str(other / "dashboard-key.pem"),
            "connect_certificate": str(other / "dashboard.pem"),
            "enable_mtls": True,
        },
    )
    with pytest.raises(LiveError):
        open_session(client(forged))


def test_the_building_network_blocks_run_as_written(tmp_path: Path, children: list[Child]) -> None:
    certs = make_certs(tmp_path / "certs")
    port = free_port()
    files = doc_files(tmp_path, certs, port)
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
