"""Floor detection cost: per-sample time of the online detector, throughput of the paper's
batch method (figures printed; the targets are in the floor-detection issue: <= 10 us per
sample for the online detector in CPython on one core)."""

from __future__ import annotations

import statistics
import time

import numpy as np

from baromap import logs
from baromap.evaluation.floors import sim_odometry
from baromap.floors import OnlineFloorDetector, detect_floors
from baromap.messages import Odometry, PressureSample
from baromap.sim.scenario import make_scenario, pressure_run

TARGET_US = 10.0


def main() -> None:
    logs.configure("console", "WARNING")
    run = pressure_run(0)  # 46 min at 25 Hz, drift, ventilation spikes, revisits
    samples = [
        PressureSample(t, p, c)
        for t, p, c in zip(
            run.t_ns.tolist(), run.pressure_pa.tolist(), run.temperature_c.tolist(), strict=True
        )
    ]
    n = len(samples)
    timings = []
    for _ in range(5):
        detector = OnlineFloorDetector()
        update = detector.update
        start = time.perf_counter()
        for sample in samples:
            update(sample)
        timings.append(time.perf_counter() - start)
    per_sample_us = statistics.median(timings) / n * 1e6
    verdict = "meets" if per_sample_us <= TARGET_US else "MISSES"
    print(
        f"online detector: {per_sample_us:.2f} us per sample (median of 5 passes over {n} "
        f"samples, 46 min at 25 Hz), {verdict} the {TARGET_US:g} us target; "
        f"{1e6 / per_sample_us / 25.0:.0f}x real time at 25 Hz"
    )
    detector_state = []
    start = time.perf_counter()
    for _ in range(10_000):
        detector_state.append(detector.state())
    print(f"online detector: state() costs {(time.perf_counter() - start) / 1e4 * 1e6:.1f} us")
    # With the robot's odometry (10 Hz) interleaved, as the daemon feeds it.
    odo_t, odo_x, odo_y = sim_odometry(make_scenario(0))
    stream: list[PressureSample | Odometry] = [
        Odometry(t, x, y, 0.0)
        for t, x, y in zip(odo_t.tolist(), odo_x.tolist(), odo_y.tolist(), strict=True)
    ]
    stream += samples
    stream.sort(key=lambda m: m.t_ns)
    timings = []
    for _ in range(5):
        detector = OnlineFloorDetector()
        start = time.perf_counter()
        for message in stream:
            if isinstance(message, Odometry):
                detector.update_odometry(message)
            else:
                detector.update(message)
        timings.append(time.perf_counter() - start)
    with_odometry = statistics.median(timings) / n * 1e6
    print(
        f"online detector with odometry: {with_odometry:.2f} us per pressure sample "
        f"(odometry updates included; {len(stream) - n} poses at 10 Hz)"
    )

    t, p = run.t_ns, run.pressure_pa
    timings = []
    for _ in range(5):
        start = time.perf_counter()
        detect_floors(t, p, method="paper")
        timings.append(time.perf_counter() - start)
    paper = statistics.median(timings)
    print(
        f"paper method (batch): {n / paper / 1e6:.1f} M samples/s "
        f"({paper * 1e3:.1f} ms for the run, median of 5)"
    )
    timings = []
    for _ in range(3):
        start = time.perf_counter()
        detect_floors(t, p, np.asarray(run.temperature_c), method="online")
        timings.append(time.perf_counter() - start)
    batch_online = statistics.median(timings)
    print(
        f"detect_floors online (batch wrapper, incl. step fits): "
        f"{n / batch_online / 1e6:.2f} M samples/s ({batch_online * 1e3:.0f} ms for the run)"
    )


if __name__ == "__main__":
    main()
