"""Contact schedules and the gait library (paper Sec. IV-D; gait timings in ``docs/settings.md``).

Contact flags (``cafe_mpc.core.contacts``) have one bool per foot in the robot's leg order
(``FL, FR, HL, HR``), ``True`` for stance. A ``ContactSchedule`` is an ordered, gap-free list of
``ContactPhase`` (stance flags and start/end times); the problem builder cuts it into whole-body phases
over the prediction window (a new phase at every contact change, Sec. IV-D). Gaits are data (``GAITS``),
periodic cycles of ``(flags, duration)``.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from cafe_mpc.core.contacts import ContactFlags, as_contact_flags, flags_to_string

TIME_TOLERANCE = 1e-9
"""Phases (or window slices) shorter than this are treated as empty; times closer than this are equal."""


@dataclass(frozen=True)
class ContactPhase:
    """A time interval ``[start, end)`` with constant stance flags."""

    stance: ContactFlags
    start: float
    end: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "stance", as_contact_flags(self.stance, "phase stance flags"))
        if not (math.isfinite(self.start) and math.isfinite(self.end)):
            raise ValueError(f"phase times must be finite, got [{self.start}, {self.end}]")
        if self.end - self.start <= TIME_TOLERANCE:
            raise ValueError(
                f"phase {flags_to_string(self.stance)} has no duration: [{self.start}, {self.end}] "
                "(a phase needs end > start)"
            )

    @property
    def duration(self) -> float:
        return self.end - self.start

    @property
    def swing(self) -> ContactFlags:
        return tuple(not s for s in self.stance)  # type: ignore[return-value]

    @property
    def n_stance(self) -> int:
        return sum(self.stance)


class ContactSchedule:
    """Ordered, contiguous contact phases (paper Sec. IV-D: the contact sequence and timing are known)."""

    def __init__(self, phases: Sequence[ContactPhase]) -> None:
        phases = tuple(phases)
        if not phases:
            raise ValueError("a contact schedule needs at least one phase")
        for index, phase in enumerate(phases):
            if not isinstance(phase, ContactPhase):
                raise ValueError(f"schedule entry {index} is not a ContactPhase: {phase!r}")
        for index, (phase, following) in enumerate(itertools.pairwise(phases)):
            if abs(phase.end - following.start) > TIME_TOLERANCE:
                raise ValueError(
                    f"schedule phases {index} and {index + 1} are not contiguous: "
                    f"phase {index} ends at {phase.end}, phase {index + 1} starts at {following.start}"
                )
        self.phases: tuple[ContactPhase, ...] = phases
        self._starts = [phase.start for phase in phases]

    @classmethod
    def from_sequence(cls, start: float, sequence: Iterable[tuple[Sequence[bool], float]]) -> ContactSchedule:
        """Build from ``[(flags, duration), ...]`` starting at ``start``."""
        phases, t = [], float(start)
        for flags, duration in sequence:
            if not duration > TIME_TOLERANCE:
                raise ValueError(f"phase {flags_to_string(flags)} has no duration ({duration})")
            phases.append(ContactPhase(as_contact_flags(flags), t, t + float(duration)))
            t += float(duration)
        return cls(phases)

    @property
    def start(self) -> float:
        return self.phases[0].start

    @property
    def end(self) -> float:
        return self.phases[-1].end

    def __len__(self) -> int:
        return len(self.phases)

    def __iter__(self):
        return iter(self.phases)

    def __repr__(self) -> str:
        body = ", ".join(f"{flags_to_string(p.stance)}[{p.start:.3f},{p.end:.3f})" for p in self.phases)
        return f"ContactSchedule({body})"

    def phase_index_at(self, t: float) -> int:
        """Index of the phase containing ``t`` (a switch time belongs to the phase that starts there;
        the schedule's end time belongs to the last phase)."""
        if t < self.start - TIME_TOLERANCE or t > self.end + TIME_TOLERANCE:
            raise ValueError(f"time {t} is outside the schedule [{self.start}, {self.end}]")
        index = bisect.bisect_right(self._starts, t + TIME_TOLERANCE) - 1
        return min(max(index, 0), len(self.phases) - 1)

    def flags_at(self, t: float) -> ContactFlags:
        """Stance flags at time ``t``."""
        return self.phases[self.phase_index_at(t)].stance

    def phases_in_window(self, t0: float, t1: float) -> list[ContactPhase]:
        """The phases intersecting ``[t0, t1]``, clipped to the window (slivers shorter than the tolerance
        are dropped). Raises when the window is empty or leaves the schedule."""
        if not t1 - t0 > TIME_TOLERANCE:
            raise ValueError(f"empty window [{t0}, {t1}]")
        if t0 < self.start - TIME_TOLERANCE or t1 > self.end + TIME_TOLERANCE:
            raise ValueError(f"window [{t0}, {t1}] leaves the schedule [{self.start}, {self.end}]")
        clipped = []
        for phase in self.phases:
            start, end = max(phase.start, t0), min(phase.end, t1)
            if end - start > TIME_TOLERANCE:
                clipped.append(ContactPhase(phase.stance, start, end))
        return clipped

    def window(self, t0: float, t1: float) -> ContactSchedule:
        """The schedule restricted to ``[t0, t1]``."""
        return ContactSchedule(self.phases_in_window(t0, t1))

    def switch_times(self) -> list[float]:
        """Times at which the stance flags change (phase boundaries between different flags)."""
        return [
            following.start
            for phase, following in zip(self.phases[:-1], self.phases[1:], strict=True)
            if phase.stance != following.stance
        ]

    def merged(self) -> ContactSchedule:
        """Adjacent phases with identical flags merged into one."""
        merged = [self.phases[0]]
        for phase in self.phases[1:]:
            if phase.stance == merged[-1].stance:
                merged[-1] = ContactPhase(phase.stance, merged[-1].start, phase.end)
            else:
                merged.append(phase)
        return ContactSchedule(merged)

    def then(self, other: ContactSchedule) -> ContactSchedule:
        """This schedule followed by ``other`` shifted to start at this schedule's end."""
        shift = self.end - other.start
        shifted = [ContactPhase(p.stance, p.start + shift, p.end + shift) for p in other.phases]
        return ContactSchedule([*self.phases, *shifted])


@dataclass(frozen=True)
class GaitCycle:
    """A periodic gait: a cycle of ``(stance flags, duration)`` (durations in seconds)."""

    name: str
    cycle: tuple[tuple[ContactFlags, float], ...]

    def __post_init__(self) -> None:
        if not self.cycle:
            raise ValueError(f"gait {self.name!r} has no phases")
        normalised = []
        for index, entry in enumerate(self.cycle):
            try:
                flags, duration = entry
            except (TypeError, ValueError) as error:
                raise ValueError(f"gait {self.name!r} phase {index}: expected (flags, duration)") from error
            duration = float(duration)
            if not (math.isfinite(duration) and duration > TIME_TOLERANCE):
                raise ValueError(f"gait {self.name!r} phase {index} has no duration ({duration})")
            normalised.append((as_contact_flags(flags, f"gait {self.name!r} phase {index} flags"), duration))
        object.__setattr__(self, "cycle", tuple(normalised))

    @property
    def period(self) -> float:
        return sum(duration for _, duration in self.cycle)

    @property
    def support_factor(self) -> float:
        """Average vertical force of a stance foot over the cycle, in units of the robot's weight.

        Over one period the feet must deliver the weight's impulse ``m g T``; shared over the stance
        foot-time ``sum(n_stance * duration)`` a stance foot carries ``m g T / sum(...)`` on average: 1/4
        standing, 1/2 trotting, 1 bounding (half the time in flight, two feet), 3/4 pronking.
        """
        foot_time = sum(sum(flags) * duration for flags, duration in self.cycle)
        if foot_time <= 0:
            raise ValueError(f"gait {self.name!r} never touches the ground")
        return self.period / foot_time

    def flags_at(self, t: float, t0: float = 0.0) -> ContactFlags:
        """Stance flags at time ``t`` for a cycle that starts at ``t0`` (and repeats forever)."""
        tau = (t - t0) % self.period
        elapsed = 0.0
        for flags, duration in self.cycle:
            elapsed += duration
            if tau < elapsed - TIME_TOLERANCE:
                return flags
        return self.cycle[0][0]

    def schedule(self, start: float, end: float, cycle_start: float | None = None) -> ContactSchedule:
        """The gait repeated over ``[start, end]`` (a cycle begins at ``cycle_start``, default ``start``),
        adjacent identical phases merged."""
        if not end - start > TIME_TOLERANCE:
            raise ValueError(f"empty schedule window [{start}, {end}]")
        cycle_start = start if cycle_start is None else cycle_start
        n_before = math.floor((start - cycle_start) / self.period + TIME_TOLERANCE)
        t = cycle_start + n_before * self.period
        phases: list[ContactPhase] = []
        while t < end - TIME_TOLERANCE:
            for flags, duration in self.cycle:
                phase_start, phase_end = max(t, start), min(t + duration, end)
                if phase_end - phase_start > TIME_TOLERANCE:
                    if phases and phases[-1].stance == flags:
                        phases[-1] = ContactPhase(flags, phases[-1].start, phase_end)
                    else:
                        phases.append(ContactPhase(flags, phase_start, phase_end))
                t += duration
                if t >= end - TIME_TOLERANCE:
                    break
        return ContactSchedule(phases)


def _gait(name: str, *cycle: tuple[str, float]) -> GaitCycle:
    """Gait from readable stance strings ("1001" = FL and HR in stance)."""
    return GaitCycle(name, tuple((tuple(c == "1" for c in flags), duration) for flags, duration in cycle))


GAITS: dict[str, GaitCycle] = {
    # Authors' gait timings (docs/settings.md, "Gaits"; order FL, FR, HL, HR; seconds).
    "trot": _gait("trot", ("1001", 0.25), ("0110", 0.25)),
    "pace": _gait("pace", ("1010", 0.25), ("0101", 0.25)),
    "bound": _gait("bound", ("1100", 0.10), ("0000", 0.10), ("0011", 0.10), ("0000", 0.10)),
    "pronk": _gait("pronk", ("1111", 0.10), ("0000", 0.20)),
    "flying_trot": _gait("flying_trot", ("1001", 0.15), ("0000", 0.10), ("0110", 0.15), ("0000", 0.10)),
    "flying_pace": _gait("flying_pace", ("1010", 0.15), ("0000", 0.10), ("0101", 0.15), ("0000", 0.10)),
    "stand": _gait("stand", ("1111", 0.50)),
    # MIT Cheetah-Software's convex-MPC timings of the Mini Cheetah (docs/settings.md, "Gaits"): a cycle of
    # ten 26 ms segments (the MPC step, 13 ticks at 500 Hz). Bound: each pair 4 segments in stance, a
    # one-segment flight after each; pronk: 4 segments on all feet, 6 in the air; pace: 5 segments a side.
    "bound_short_flight": _gait(
        "bound_short_flight", ("1100", 0.104), ("0000", 0.026), ("0011", 0.104), ("0000", 0.026)
    ),
    "pronk_short_flight": _gait("pronk_short_flight", ("1111", 0.104), ("0000", 0.156)),
    "pace_short_stance": _gait("pace_short_stance", ("1010", 0.13), ("0101", 0.13)),
}
"""The gait library (data). Add a gait by adding a ``GaitCycle``."""


def get_gait(name: str) -> GaitCycle:
    """A gait of ``GAITS`` by name (``-`` and ``_`` are interchangeable)."""
    key = name.replace("-", "_").lower()
    if key not in GAITS:
        raise ValueError(f"unknown gait {name!r}; known gaits: {', '.join(sorted(GAITS))}")
    return GAITS[key]
