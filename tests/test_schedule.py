"""Contact schedules and the gait library."""

from __future__ import annotations

import pytest

from cafe_mpc.core.contacts import (
    ALL_STANCE,
    FLIGHT,
    as_contact_flags,
    flags_to_string,
    takeoff_flags,
    touchdown_flags,
)
from cafe_mpc.ocp.contact_schedule import GAITS, ContactPhase, ContactSchedule, GaitCycle, get_gait


def test_contact_flag_validation():
    assert as_contact_flags([1, 0, 0, 1]) == (True, False, False, True)
    for bad in [(1, 0, 0), (1, 0, 0, 1, 1), (1, 2, 0, 1), ("a", 0, 0, 1), 5]:
        with pytest.raises(ValueError):
            as_contact_flags(bad)
    assert touchdown_flags((1, 0, 0, 1), (1, 1, 1, 1)) == (False, True, True, False)
    assert takeoff_flags((1, 1, 1, 1), (0, 1, 1, 0)) == (True, False, False, True)
    assert flags_to_string((1, 0, 0, 1)) == "FL+HR"
    assert flags_to_string(FLIGHT) == "flight"


def test_phase_validation():
    with pytest.raises(ValueError, match="no duration"):
        ContactPhase(ALL_STANCE, 0.3, 0.3)
    with pytest.raises(ValueError):
        ContactPhase(ALL_STANCE, 0.3, 0.2)
    with pytest.raises(ValueError):
        ContactPhase((1, 1, 1), 0.0, 0.1)
    with pytest.raises(ValueError):
        ContactSchedule([])
    with pytest.raises(ValueError, match="contiguous"):
        ContactSchedule([ContactPhase(ALL_STANCE, 0.0, 0.1), ContactPhase(FLIGHT, 0.2, 0.3)])
    with pytest.raises(ValueError, match="no duration"):
        ContactSchedule.from_sequence(0.0, [(ALL_STANCE, 0.1), (FLIGHT, 0.0)])
    with pytest.raises(ValueError):
        GaitCycle("bad", (((1, 1, 1, 1), 0.0),))
    with pytest.raises(ValueError):
        GaitCycle("bad", ())


def test_schedule_queries():
    schedule = ContactSchedule.from_sequence(1.0, [((1, 1, 0, 0), 0.1), (FLIGHT, 0.1), ((0, 0, 1, 1), 0.1)])
    assert (schedule.start, schedule.end) == (1.0, pytest.approx(1.3))
    assert schedule.flags_at(1.0) == (True, True, False, False)
    assert schedule.flags_at(1.05) == (True, True, False, False)
    assert schedule.flags_at(1.1) == FLIGHT  # a switch time belongs to the phase starting there
    assert schedule.flags_at(1.3) == (False, False, True, True)
    with pytest.raises(ValueError):
        schedule.flags_at(0.99)
    window = schedule.phases_in_window(1.05, 1.25)
    assert [p.stance for p in window] == [(True, True, False, False), FLIGHT, (False, False, True, True)]
    assert window[0].start == pytest.approx(1.05) and window[0].duration == pytest.approx(0.05)
    assert window[-1].end == pytest.approx(1.25)
    # A window ending exactly on a switch does not produce a zero-length sliver.
    assert len(schedule.phases_in_window(1.0, 1.1)) == 1
    with pytest.raises(ValueError):
        schedule.phases_in_window(1.2, 1.2)
    assert schedule.switch_times() == [pytest.approx(1.1), pytest.approx(1.2)]


def test_merge_and_then():
    schedule = ContactSchedule.from_sequence(0.0, [(ALL_STANCE, 0.1), (ALL_STANCE, 0.2), (FLIGHT, 0.1)])
    merged = schedule.merged()
    assert len(merged) == 2 and merged.phases[0].duration == pytest.approx(0.3)
    joined = merged.then(ContactSchedule.from_sequence(5.0, [(ALL_STANCE, 0.5)]))
    assert joined.end == pytest.approx(0.9)
    assert joined.flags_at(0.45) == ALL_STANCE


def test_gait_library():
    assert set(GAITS) == {
        "trot",
        "pace",
        "bound",
        "pronk",
        "flying_trot",
        "flying_pace",
        "stand",
        "bound_short_flight",
        "pronk_short_flight",
        "pace_short_stance",
    }
    assert get_gait("flying-trot") is GAITS["flying_trot"]
    with pytest.raises(ValueError, match="known gaits"):
        get_gait("gallop")
    assert GAITS["trot"].period == pytest.approx(0.5)
    assert GAITS["bound"].period == pytest.approx(0.4)
    assert GAITS["pronk"].period == pytest.approx(0.3)
    assert GAITS["flying_pace"].period == pytest.approx(0.5)
    trot = GAITS["trot"]
    assert trot.flags_at(0.1) == (True, False, False, True)  # FL + HR
    assert trot.flags_at(0.3) == (False, True, True, False)
    assert trot.flags_at(0.6) == (True, False, False, True)  # periodic
    assert GAITS["pace"].flags_at(0.0) == (True, False, True, False)  # left pair
    assert GAITS["bound"].flags_at(0.15) == FLIGHT
    assert GAITS["bound"].flags_at(0.25) == (False, False, True, True)
    for gait in GAITS.values():
        for flags, duration in gait.cycle:
            assert len(flags) == 4 and duration > 0


def test_mit_timings():
    """MIT Cheetah-Software's convex-MPC gaits: ten 26 ms segments a cycle; the bound's pairs 104 ms in
    stance with a 26 ms flight after each, the pronk 104 ms down and 156 ms up, the pace 130 ms a side."""
    bound, pronk, pace = GAITS["bound_short_flight"], GAITS["pronk_short_flight"], GAITS["pace_short_stance"]
    for gait in (bound, pronk, pace):
        assert gait.period == pytest.approx(0.26)
    assert bound.flags_at(0.05) == (True, True, False, False)
    assert bound.flags_at(0.11) == FLIGHT
    assert bound.flags_at(0.20) == (False, False, True, True)
    assert bound.flags_at(0.25) == FLIGHT
    assert bound.support_factor == pytest.approx(0.26 / 0.416)  # 0.625 of the weight per stance foot
    assert pronk.flags_at(0.1) == ALL_STANCE and pronk.flags_at(0.11) == FLIGHT
    assert pace.flags_at(0.0) == (True, False, True, False)
    assert pace.flags_at(0.14) == (False, True, False, True)


def test_gait_schedule_over_a_window():
    bound = GAITS["bound"]
    schedule = bound.schedule(0.05, 0.55, cycle_start=0.0)
    assert schedule.start == pytest.approx(0.05) and schedule.end == pytest.approx(0.55)
    expected = [
        ((True, True, False, False), 0.05, 0.10),
        (FLIGHT, 0.10, 0.20),
        ((False, False, True, True), 0.20, 0.30),
        (FLIGHT, 0.30, 0.40),
        ((True, True, False, False), 0.40, 0.50),
        (FLIGHT, 0.50, 0.55),
    ]
    assert len(schedule) == len(expected)
    for phase, (flags, start, end) in zip(schedule, expected, strict=True):
        assert phase.stance == flags
        assert phase.start == pytest.approx(start) and phase.end == pytest.approx(end)
    for t in (0.05, 0.12, 0.33, 0.47, 0.55):
        assert schedule.flags_at(t) == bound.flags_at(t)
    stand = GAITS["stand"].schedule(0.0, 2.0)
    assert len(stand) == 1 and stand.phases[0].duration == pytest.approx(2.0)  # repeats merged
