"""How well the VWBC's contact detector sees the plant's contacts, in closed loop (fixed latency).

Runs presets with ``vwbc.stance_source=detected`` and compares, tick by tick, the detector's stance with the
plant's contact flags (MuJoCo's) and with the plan's schedule:

* **delay**: for every plant touchdown (a foot's contact flag off -> on, after at least 20 ms off), the time
  until the detector calls the foot in contact (median, p95, max; a touchdown it never sees within 100 ms is
  *missed*);
* **false contact**: ticks the detector calls a foot in contact while the plant has had it off for more than
  20 ms (not a bounce);
* **false touchdowns**: the detector's touchdowns (a foot's flag off -> on) with no plant contact of that
  foot within ``NEAR`` of them (false contact ticks count the lift-offs the detector sees late too);
* **early touchdowns**: feet the detector put in stance before their planned touchdown (on a flat floor in a
  nominal run these are real: the plant's foot was already down).

Usage::

    python benchmarks/contact_detection.py                       # trot, bound, pronk, 10 s, estimator on
    python benchmarks/contact_detection.py --presets trot --set estimator=ground_truth
"""

from __future__ import annotations

import argparse

import numpy as np

from cafe_mpc.config import load_config
from cafe_mpc.low_level import contact_detection
from cafe_mpc_lab.experiments.run import simulate_run

BOUNCE = 0.02
"""s: a plant contact that was off for less than this is a bounce, not a new touchdown."""
MISS = 0.1
"""s: a touchdown not seen within this is missed."""
NEAR = 0.01
"""s: a detected touchdown with no plant contact of its foot within this of it is false."""


class DetectorRecorder:
    """While active (``with``), every ``ContactDetector.update`` call's time and output are kept."""

    def __init__(self) -> None:
        self.times: list[float] = []
        self.flags: list[np.ndarray] = []
        self.detectors: list[contact_detection.ContactDetector] = []
        self._original = contact_detection.ContactDetector.update

    def __enter__(self) -> DetectorRecorder:
        original, recorder = self._original, self

        def update(detector, t, measurement, plan, *applied):
            flags = original(detector, t, measurement, plan, *applied)
            if detector not in recorder.detectors:
                recorder.detectors.append(detector)
            recorder.times.append(float(t))
            recorder.flags.append(flags.copy())
            return flags

        contact_detection.ContactDetector.update = update
        return self

    def __exit__(self, *exc) -> None:
        contact_detection.ContactDetector.update = self._original


def touchdown_delays(plant_time, plant, times, detected) -> tuple[list[float], int, int]:
    """Delays of the detector's touchdowns after the plant's, missed touchdowns, false-contact ticks."""
    bounce_ticks = round(BOUNCE / float(np.median(np.diff(plant_time))))
    rows = np.searchsorted(times, plant_time - 1e-9)
    aligned = (rows < len(times)) & (np.abs(times[np.minimum(rows, len(times) - 1)] - plant_time) < 1e-6)
    delays, missed, false_ticks = [], 0, 0
    for foot in range(plant.shape[1]):
        off_run = 0
        for i in range(1, len(plant_time)):
            if not plant[i, foot]:
                off_run += 1
                if off_run > bounce_ticks and aligned[i] and detected[rows[i], foot]:
                    false_ticks += 1
                continue
            if off_run > bounce_ticks:  # a touchdown
                window = (times >= plant_time[i] - 1e-9) & (times <= plant_time[i] + MISS)
                hits = np.nonzero(detected[window, foot])[0]
                if len(hits):
                    delays.append(float(times[window][hits[0]] - plant_time[i]))
                else:
                    missed += 1
            off_run = 0
    return delays, missed, false_ticks


def false_touchdowns(plant_time, plant, times, detected) -> int:
    """The detector's touchdowns (flag off -> on) with no plant contact of that foot within ``NEAR``."""
    count = 0
    rising = detected[1:] & ~detected[:-1]
    for row, foot in zip(*np.nonzero(rising), strict=True):
        t = times[row + 1]
        near = (plant_time >= t - NEAR - 1e-9) & (plant_time <= t + NEAR + 1e-9)
        if not np.any(plant[near, foot]):
            count += 1
    return count


def evaluate(preset: str, duration: float, overrides: list[str]) -> dict:
    config = load_config(
        preset,
        ["vwbc.stance_source=detected", "mpc.latency=fixed", f"simulation.duration={duration}", *overrides],
    )
    with DetectorRecorder() as recorder:
        _, _, log = simulate_run(config)
    times, detected = np.array(recorder.times), np.array(recorder.flags)
    delays, missed, false_ticks = touchdown_delays(log.time, log.contacts.astype(bool), times, detected)
    delays_ms = 1e3 * np.array(delays) if delays else np.array([np.nan])
    statistics = recorder.detectors[0].statistics() if recorder.detectors else {}
    return {
        "preset": preset,
        "touchdowns": len(delays) + missed,
        "missed": missed,
        "delay_ms_median": float(np.median(delays_ms)),
        "delay_ms_p95": float(np.percentile(delays_ms, 95)),
        "delay_ms_max": float(np.max(delays_ms)),
        "false_contact_ticks": false_ticks,
        "false_touchdowns": false_touchdowns(log.time, log.contacts.astype(bool), times, detected),
        "sim_time": float(log.time[-1]),
        **statistics,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--presets", default="trot,bound,pronk")
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    header = ["preset", "simulated [s]", "touchdowns", "missed", "delay median / p95 / max [ms]"]
    header += ["false touchdowns", "false-contact ticks", "early touchdowns", "their lead [ms]"]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for preset in args.presets.split(","):
        row = evaluate(preset.strip(), args.duration, args.overrides)
        delays = f"{row['delay_ms_median']:.0f} / {row['delay_ms_p95']:.0f} / {row['delay_ms_max']:.0f}"
        cells = [row["preset"], f"{row['sim_time']:.1f}", row["touchdowns"], row["missed"], delays]
        lead = row.get("early_touchdown_lead_s_mean")
        cells += [row["false_touchdowns"], row["false_contact_ticks"], row.get("early_touchdowns", "n/a")]
        cells += [f"{1e3 * lead:.0f}" if lead is not None else "-"]
        print("| " + " | ".join(str(cell) for cell in cells) + " |", flush=True)


if __name__ == "__main__":
    main()
