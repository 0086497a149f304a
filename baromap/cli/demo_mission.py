"""The demo's mission: which simulated run the twins play, and how fast.

Short enough to watch, long enough to show the product: three floors, three elevator rides and
a revisit (start on floor 1, up to 2, down to 0, back to 1), ten simulated minutes, so the robot
has time to leave the lobby and explore a little on each floor (a cheapest excursion from the
lobby takes 70-90 s at the P3-AT's indoor speeds; a six-minute mission only drives in and out of
the car).

The twins play it ``speed`` times faster than real time. The daemon stamps what it receives on
the host's clock, so the recording is the mission compressed by ``speed``, and everything that
judges motion in seconds sees the robot and the car move ``speed`` times faster. The daemon's
floor detector is therefore configured for that world: its durations divided by ``speed``, its
rates multiplied (:meth:`Mission.floor_settings`), as a detector tuned for a faster robot would
be. ``bench/demo.py`` measures what the speed does to the recording (scans per metre, odometry,
the detector with and without this, the maps).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from baromap.errors import ConfigError

#: Fastest the twins may run for the demo. The lines set the limit: the LMS200's 500 kbaud
#: carries 134 scans a second (the twin then sends fewer scans per simulated second), the
#: P3-AT's SIPs need ``base_baud`` (9600 baud carries 26 a second: 2.6x its 10 Hz), the
#: barometer's 115200 baud some 570 samples a second (11x its 50 Hz).
MAX_SPEED = 8.0
DEFAULT_SPEED = 6.0
DEFAULT_MINUTES = 10.0


@dataclass(frozen=True, slots=True)
class Mission:
    seed: int = 0
    floors: int = 3
    route: tuple[int, ...] = (1, 2, 0, 1)
    minutes: float = DEFAULT_MINUTES
    speed: float = DEFAULT_SPEED
    robot: str = "demo"
    #: The robot's host port speed (ARCOS HostBaud), so SIPs keep up with the speed.
    base_baud: int = 115200

    def __post_init__(self) -> None:
        if not 0 < self.speed <= MAX_SPEED:
            raise ConfigError(f"speed must be above 0 and at most {MAX_SPEED:g}, not {self.speed}")
        if not 0 < self.minutes <= 60:
            raise ConfigError(f"minutes must be above 0 and at most 60, not {self.minutes}")

    def floor_settings(self) -> dict[str, float]:
        """The daemon's ``[floors]`` table for this speed: the detector's defaults with every
        duration (``*_s``) divided by ``speed`` and every rate (``*_m_s``) multiplied."""
        from baromap.floors import FloorDetectorConfig

        defaults = FloorDetectorConfig()
        table: dict[str, float] = {}
        for f in fields(FloorDetectorConfig):
            value = getattr(defaults, f.name)
            if f.name.endswith("_m_s"):
                table[f.name] = value * self.speed
            elif f.name.endswith("_s"):
                table[f.name] = value / self.speed
        return table

    @property
    def wall_s(self) -> float:
        """How long the mission lasts in real time."""
        return self.minutes * 60.0 / self.speed

    def sim_args(self) -> list[str]:
        """The ``baromap sim`` options that play this mission."""
        return [
            "--seed",
            str(self.seed),
            "--floors",
            str(self.floors),
            "--minutes",
            f"{self.minutes:g}",
            "--route",
            ",".join(str(f) for f in self.route),
            "--speed",
            f"{self.speed:g}",
        ]
