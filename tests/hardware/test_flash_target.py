"""``make -C firmware flash PORT=...``: avrdude writes and verifies the firmware through a board's
bootloader, here a stand-in for an Uno's (optiboot, STK500v1) on a pseudo-terminal.

The stand-in answers the commands avrdude's ``arduino`` programmer sends (sync, parameters,
device set-up, signature, load address, program and read page, leave) and keeps what was
written, so avrdude's own verification reads it back; the test also compares that memory with
the HEX file. What it cannot show: the reset into the bootloader by DTR, and timing.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import threading
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest

FIRMWARE = Path(__file__).resolve().parents[2] / "firmware"
HEX = FIRMWARE / "build" / "baromap_baro.hex"
SIGNATURE = bytes((0x1E, 0x95, 0x0F))  # ATmega328P
INSYNC, OK, EOP = 0x14, 0x10, 0x20
#: Command -> number of argument bytes before the end-of-packet byte (STK500v1).
ARGUMENTS = {0x30: 0, 0x41: 1, 0x42: 20, 0x45: 5, 0x50: 0, 0x51: 0, 0x55: 2, 0x56: 4, 0x75: 0}


class Bootloader:
    """An STK500v1 bootloader on a pty, with 32 KiB of flash."""

    def __init__(self) -> None:
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        self.flash = bytearray(b"\xff" * 32768)
        self.address = 0
        self.pages_written = 0
        self._stop = threading.Event()
        self._buffer = bytearray()
        self._thread = threading.Thread(target=self._run, name="fake-optiboot", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        os.close(self.master)
        os.close(self._slave)

    def _take(self, n: int) -> bytes | None:
        if len(self._buffer) < n:
            return None
        out = bytes(self._buffer[:n])
        del self._buffer[:n]
        return out

    def _run(self) -> None:
        import select

        while not self._stop.is_set():
            if select.select([self.master], [], [], 0.05)[0]:
                try:
                    self._buffer += os.read(self.master, 4096)
                except OSError:
                    continue
            while self._buffer and self._step():
                pass

    def _step(self) -> bool:
        """Answer one complete command from the buffer; False if it is not complete yet."""
        command = self._buffer[0]
        if command in ARGUMENTS:
            packet = self._take(2 + ARGUMENTS[command])
            if packet is None:
                return False
            args = packet[1:-1]
            body = b""
            if command == 0x41:
                body = bytes((0x04 if args[0] in (0x81, 0x82) else 0x03,))
            elif command == 0x55:
                self.address = int.from_bytes(args, "little") * 2  # a word address
            elif command == 0x75:
                body = SIGNATURE
            elif command == 0x56:
                body = b"\x00"
            os.write(self.master, bytes((INSYNC, *body, OK)))
            return True
        if command in (0x64, 0x74):  # program page, read page: length (big-endian), memory
            head = bytes(self._buffer[:4])
            if len(head) < 4:
                return False
            length = int.from_bytes(head[1:3], "big")
            size = 4 + (length if command == 0x64 else 0) + 1
            packet = self._take(size)
            if packet is None:
                return False
            start = self.address
            if command == 0x64:
                self.flash[start : start + length] = packet[4:-1]
                self.pages_written += 1
                os.write(self.master, bytes((INSYNC, OK)))
            else:
                os.write(self.master, bytes((INSYNC, *self.flash[start : start + length], OK)))
            return True
        del self._buffer[0]  # not a command: avrdude's line noise or a resync
        return True


def _hex_image(path: Path) -> dict[int, int]:
    """Address -> byte of an Intel HEX file's data records."""
    image: dict[int, int] = {}
    for line in path.read_text().splitlines():
        record = bytes.fromhex(line[1:])
        count, address, kind = record[0], int.from_bytes(record[1:3], "big"), record[3]
        if kind == 0:
            for i, byte in enumerate(record[4 : 4 + count]):
                image[address + i] = byte
    return image


@pytest.fixture
def bootloader() -> Iterator[Bootloader]:
    board = Bootloader()
    yield board
    board.close()


@pytest.mark.parametrize("image", ["", "build/hooks/baromap_baro.elf"], ids=["release", "hooks"])
def test_make_flash_writes_and_verifies_the_firmware(bootloader: Bootloader, image: str) -> None:
    if shutil.which("avrdude") is None:
        pytest.skip("avrdude missing (apt-get install avrdude; scripts/system-deps.sh does)")
    if not HEX.is_file():
        pytest.skip(f"no firmware built ({HEX}): make -C firmware")
    command = ["make", "--no-print-directory", "-C", str(FIRMWARE), "flash"]
    command += [f"PORT={bootloader.path}"] + ([f"IMAGE={image}"] if image else [])
    result = subprocess.run(command, capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "verified" in result.stderr  # avrdude read every byte back
    assert bootloader.pages_written > 100  # the firmware is 14 kB: 111 pages of 128 bytes
    if not image:
        assert all(bootloader.flash[a] == b for a, b in _hex_image(HEX).items())


def test_make_flash_without_a_port_says_how() -> None:
    result = subprocess.run(
        ["make", "--no-print-directory", "-C", str(FIRMWARE), "-o", str(HEX), "flash"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode != 0
    assert "PORT=" in result.stderr
