"""``baromap watch`` as a person meets it: listed in help, one clear line when it cannot work."""

from __future__ import annotations

import json
import time

import pytest
from procs import endpoint, free_port

from baromap.cli.main import main
from baromap.live.settings import LiveSettings
from baromap.messages import FloorPhase, FloorState
from baromapd.live import LivePublisher


def test_watch_is_a_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "    watch " in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--connect", "tcp/127.0.0.1"], "--connect: 'tcp/127.0.0.1' needs a host and a port"),
        (["--connect", "pigeon/x:1"], "--connect: unknown protocol 'pigeon'"),
        (["--robot", "a/b"], "robot id: 'a/b' is not an id"),
        (["--seconds", "0"], "--seconds must be above 0"),
        (["--zenoh-config", "/nonexistent.json5"], "--zenoh-config: '/nonexistent.json5' is not"),
        (["--connect", "{nowhere}"], "cannot open a Zenoh client session"),
    ],
)
def test_bad_input_is_one_line_and_exit_1(
    capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    nowhere = endpoint(free_port())
    assert main(["watch", *(a.format(nowhere=nowhere) for a in argv)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("baromap: error: ") and message in err[0]


def test_text_and_json_lines_of_a_robot(capsys: pytest.CaptureFixture[str]) -> None:
    robot_ep = endpoint(free_port())
    publisher = LivePublisher(LiveSettings(listen=(robot_ep,)), "r1")
    publisher.start()
    try:
        deadline = time.monotonic() + 20
        nan = float("nan")
        unknown = FloorState(1, FloorPhase.UNKNOWN, None, None, nan, nan, nan, 1, 0)
        publisher.offer(unknown)
        while publisher.health()["published"] == 0:
            assert time.monotonic() < deadline
            time.sleep(0.02)
        assert main(["watch", "--connect", robot_ep, "--seconds", "1.5"]) == 0
        text = capsys.readouterr().out
        assert main(["watch", "--connect", robot_ep, "--seconds", "1.5", "--json"]) == 0
        lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    finally:
        publisher.stop()
    assert "r1: online" in text
    assert "r1: state: floor not known yet (unknown since" in text
    assert "nan" not in text.lower()
    (state,) = [line for line in lines if line["report"] == "state"]
    assert state["robot"] == "r1" and state["state"]["level_pa"] is None  # JSON has no NaN
    assert {"online", "answered"} <= {line["report"] for line in lines}
