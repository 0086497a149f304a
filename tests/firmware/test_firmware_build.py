"""The firmware builds within budget, keeps the Arduino sketch layout, and its C++ passes the
host unit tests that read the shared vectors (COBS, CRC, framing, BMP280 compensation)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest
from firmware_board import FIRMWARE_DIR

pytestmark = pytest.mark.firmware

SKETCH = FIRMWARE_DIR / "baromap_baro"
VECTORS = FIRMWARE_DIR / "test_vectors.txt"


def test_flash_and_ram_within_budget(firmware_size_report: str) -> None:
    flash = re.search(r"flash (\d+) bytes \(([\d.]+)% of (\d+)", firmware_size_report)
    ram = re.search(r"RAM (\d+) bytes \(([\d.]+)% of (\d+)", firmware_size_report)
    assert flash and ram, firmware_size_report
    print(firmware_size_report.strip())
    assert float(flash.group(2)) <= 60.0
    assert float(ram.group(2)) <= 50.0


def test_sketch_opens_unchanged_in_the_arduino_ide() -> None:
    """The IDE wants DIR/DIR.ino with its .h/.cpp files beside it, nothing it cannot build."""
    assert (SKETCH / "baromap_baro.ino").is_file()
    for path in SKETCH.iterdir():
        assert path.is_file(), f"{path.name}: the IDE compiles only files beside the .ino"
        assert path.suffix in {".ino", ".h", ".cpp"}, path.name


@pytest.mark.parametrize(
    "pattern",
    [r"\bString\b", r"\bprintf\b", r"\bSerial\b", r"\bprint(ln)?\s*\(", r"\bmalloc\b", r"\bnew\b"],
)
def test_firmware_has_no_text_output_or_heap(pattern: str) -> None:
    """No text ever on the data port, no heap: fixed buffers only."""
    for path in SKETCH.iterdir():
        code = re.sub(r"//.*|/\*.*?\*/", "", path.read_text(), flags=re.S)
        assert not re.search(pattern, code), f"{path.name} uses {pattern}"


def test_host_unit_tests_pass(host_tests_binary: Path) -> None:
    result = subprocess.run(
        [str(host_tests_binary), str(VECTORS)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    print(result.stdout)
    assert result.returncode == 0, result.stdout + result.stderr
    summary = re.search(r"host tests: (\d+) checks, (\d+) failed", result.stdout)
    assert summary and int(summary.group(2)) == 0
    assert int(summary.group(1)) > 400
    # Every kind of vector in the shared file was exercised.
    counts = dict(re.findall(r"(\w+)=(\d+)", result.stdout.splitlines()[0]))
    assert set(counts) == {
        "bad",
        "bmp280",
        "bmp280_calib",
        "cobs",
        "crc",
        "frame",
        "ms5611",
        "ms5611_prom",
    }


def _bosch_reference(words: list[int], adc_t: int, adc_p: int) -> tuple[int, int, int]:
    """Bosch's integer compensation in Python (arbitrary precision, C division semantics)."""
    t1, t2, t3, p1, p2, p3, p4, p5, p6, p7, p8, p9 = words
    d = (adc_t >> 4) - t1
    t_fine = ((((adc_t >> 3) - (t1 << 1)) * t2) >> 11) + ((((d * d) >> 12) * t3) >> 14)
    temperature = (t_fine * 5 + 128) >> 8
    v1 = t_fine - 128000
    v2 = v1 * v1 * p6 + ((v1 * p5) << 17) + (p4 << 35)
    v1 = ((v1 * v1 * p3) >> 8) + ((v1 * p2) << 12)
    v1 = (((1 << 47) + v1) * p1) >> 33
    if v1 == 0:
        return t_fine, temperature, 0
    num = ((1048576 - adc_p) << 31) - v2
    num *= 3125
    p = abs(num) // abs(v1) * (1 if (num >= 0) == (v1 >= 0) else -1)
    v1 = (p9 * (p >> 13) * (p >> 13)) >> 25
    v2 = (p8 * p) >> 19
    return t_fine, temperature, ((p + v1 + v2) >> 8) + (p7 << 4)


def test_compensation_vectors_agree_with_an_independent_reference() -> None:
    names = ["T1", "T2", "T3", "P1", "P2", "P3", "P4", "P5", "P6", "P7", "P8", "P9"]
    checked = 0
    for line in VECTORS.read_text().splitlines():
        if not line.startswith("bmp280 "):
            continue
        v = dict(token.split("=", 1) for token in line.split()[1:])
        words = [int(v[n]) for n in names]
        expected = (int(v["t_fine"]), int(v["T"]), int(v["P"]))
        assert _bosch_reference(words, int(v["adc_T"]), int(v["adc_P"])) == expected, v["name"]
        checked += 1
    assert checked >= 5
    # The data sheet's worked example: 25.08 degC and 100653.27 Pa (double formula).
    t_fine, temp, p = _bosch_reference(
        [27504, 26435, -1000, 36477, -10685, 3024, 2855, 140, -7, 15500, -14600, 6000],
        519888,
        415148,
    )
    assert (t_fine, temp) == (128422, 2508)
    assert p / 256 == pytest.approx(100653.27, abs=0.05)


def _tdiv(a: int, b: int) -> int:
    """C integer division (truncates toward zero)."""
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b >= 0) else -q


def _ms5611_reference(c: list[int], d1: int, d2: int) -> tuple[int, int]:
    """The MS5611 data sheet's compensation with the second-order correction, in Python."""
    dt = d2 - c[5] * 256
    temp = 2000 + _tdiv(dt * c[6], 1 << 23)
    off = c[2] * (1 << 16) + _tdiv(c[4] * dt, 1 << 7)
    sens = c[1] * (1 << 15) + _tdiv(c[3] * dt, 1 << 8)
    if temp < 2000:
        cold = (temp - 2000) ** 2
        t2, off2, sens2 = _tdiv(dt * dt, 1 << 31), _tdiv(5 * cold, 2), _tdiv(5 * cold, 4)
        if temp < -1500:
            off2 += 7 * (temp + 1500) ** 2
            sens2 += _tdiv(11 * (temp + 1500) ** 2, 2)
        temp, off, sens = temp - t2, off - off2, sens - sens2
    return temp, _tdiv(_tdiv(d1 * sens, 1 << 21) - off, 1 << 7)


def _crc4(words: list[int]) -> int:
    rem = 0
    for i in range(16):
        word = words[i >> 1] & (0xFF00 if i >= 14 else 0xFFFF)
        rem ^= word & 0xFF if i & 1 else word >> 8
        for _ in range(8):
            rem = ((rem << 1) ^ 0x3000 if rem & 0x8000 else rem << 1) & 0xFFFF
    return rem >> 12


def test_ms5611_vectors_agree_with_an_independent_reference() -> None:
    checked = 0
    for line in VECTORS.read_text().splitlines():
        kind, *tokens = line.split() or [""]
        v = dict(token.split("=", 1) for token in tokens) if kind.startswith("ms5611") else {}
        if kind == "ms5611":
            c = [0] + [int(v[f"C{i}"]) for i in range(1, 7)] + [0]
            got = _ms5611_reference(c, int(v["D1"]), int(v["D2"]))
            assert got == (int(v["TEMP"]), int(v["P"])), v["name"]
            checked += 1
        elif kind == "ms5611_prom":
            raw = bytes.fromhex(v["prom"])
            words = [int.from_bytes(raw[i : i + 2], "big") for i in range(0, 16, 2)]
            dead = set(words) <= {0} or set(words) <= {0xFFFF}
            assert (not dead and _crc4(words) == words[7] & 0xF) == (v["valid"] == "1"), v["name"]
            checked += 1
    assert checked >= 6
    # The data sheet's example: 20.07 degC and 1000.09 mbar; AN520's PROM carries CRC 0xB.
    temp, p = _ms5611_reference([0, 40127, 36924, 23317, 23282, 33464, 28312, 0], 9085466, 8569150)
    assert (temp, p >> 8) == (2007, 100009)
    assert _crc4([0x3132, 0x3334, 0x3536, 0x3738, 0x3940, 0x4142, 0x4344, 0x450B]) == 0xB
