"""Contact flags: one bool per foot in the robot's leg order, ``True`` for stance.

The robots of this package are quadrupeds (``Robot`` checks it): four feet in the leg order
``FL, FR, HL, HR``. Gait schedules built from these flags live in ``cafe_mpc.ocp.contact_schedule``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

LEG_NAMES = ("FL", "FR", "HL", "HR")
N_FEET = len(LEG_NAMES)
ContactFlags = tuple[bool, bool, bool, bool]

ALL_STANCE: ContactFlags = (True, True, True, True)
FLIGHT: ContactFlags = (False, False, False, False)


def as_contact_flags(flags: Iterable, name: str = "contact flags") -> ContactFlags:
    """Validate and normalise contact flags: exactly 4 booleans (or 0/1) in leg order ``FL, FR, HL, HR``."""
    try:
        values = tuple(flags)
    except TypeError as error:
        raise ValueError(f"{name} must be a sequence of {N_FEET} booleans, got {flags!r}") from error
    if len(values) != N_FEET:
        raise ValueError(
            f"{name} must have one flag per foot ({N_FEET}, order {', '.join(LEG_NAMES)}), got {len(values)}"
        )
    normalised = []
    for value in values:
        is_boolean = isinstance(value, bool | np.bool_)
        if is_boolean or (isinstance(value, int | float) and value in (0, 1)):
            normalised.append(bool(value))
        else:
            raise ValueError(f"{name} must be booleans (or 0/1), got {flags!r}")
    return tuple(normalised)  # type: ignore[return-value]


def touchdown_flags(before: Sequence[bool], after: Sequence[bool]) -> ContactFlags:
    """Feet that are in swing in ``before`` and in stance in ``after`` (they touch down at the switch)."""
    before, after = as_contact_flags(before), as_contact_flags(after)
    return tuple(a and not b for b, a in zip(before, after, strict=True))  # type: ignore[return-value]


def takeoff_flags(before: Sequence[bool], after: Sequence[bool]) -> ContactFlags:
    """Feet that are in stance in ``before`` and in swing in ``after`` (they lift off at the switch)."""
    before, after = as_contact_flags(before), as_contact_flags(after)
    return tuple(b and not a for b, a in zip(before, after, strict=True))  # type: ignore[return-value]


def flags_to_string(flags: Sequence[bool]) -> str:
    """``(True, False, False, True)`` -> ``"FL+HR"`` (``"flight"`` when no foot is in stance)."""
    names = [leg for leg, on in zip(LEG_NAMES, as_contact_flags(flags), strict=True) if on]
    return "+".join(names) if names else "flight"
