"""All three twins on one clock: what ``baromap sim`` and the demo start."""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from pathlib import Path

from baromap.sim.scenario import TwinSettings, make_scenario
from baromap.sim.twins.baro import BaroTwin
from baromap.sim.twins.base import SimClock, Started, Twin
from baromap.sim.twins.lms200 import Lms200Twin
from baromap.sim.twins.p2os import P2osTwin
from baromap.sim.twins.truth import TruthSink


class SimDevices(Started):
    """The LMS200, the P3-AT and the barometer board of one scenario, on ptys."""

    def __init__(
        self,
        *,
        seed: int = 0,
        floors: int = 6,
        minutes: float = 46.0,
        drift_hpa_per_h: float = 1.5,
        route: Sequence[int] | None = None,
        speed: float = 1.0,
        link_dir: str | Path | None = None,
        twins: TwinSettings | None = None,
        truth_sink: TruthSink | None = None,
    ) -> None:
        scenario = make_scenario(
            seed,
            floors=floors,
            minutes=minutes,
            drift_hpa_per_h=drift_hpa_per_h,
            route=route,
            twins=twins,
        )
        self.clock = SimClock(scenario, speed)
        links = Path(link_dir) if link_dir is not None else None

        def link(name: str) -> Path | None:
            return links / name if links is not None else None

        with contextlib.ExitStack() as undo:  # each twin opens a pty: close them if one fails
            self.lms200 = Lms200Twin(self.clock, link("lms200"), truth_sink=truth_sink)
            undo.callback(self.lms200.stop)
            self.p3at = P2osTwin(self.clock, link("p3at"), truth_sink=truth_sink)
            undo.callback(self.p3at.stop)
            self.baro = BaroTwin(self.clock, link("baro"), truth_sink=truth_sink)
            undo.pop_all()

    @property
    def twins(self) -> tuple[Twin, ...]:
        return (self.lms200, self.p3at, self.baro)

    def paths(self) -> dict[str, str]:
        return {t.name: t.path for t in self.twins}

    def start(self) -> SimDevices:
        try:
            for t in self.twins:
                t.start()
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self) -> None:
        for t in self.twins:
            t.stop()
