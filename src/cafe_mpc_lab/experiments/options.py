"""An experiment's own command-line options, declared as a typed model and parsed by it.

Each experiment declares ``Options``, a subclass of ``ExperimentOptions`` whose fields are its options:
``--<field with dashes>``, the field's ``description`` its help, ``metavar`` (in ``json_schema_extra``) its
placeholder, a ``bool`` field a flag. ``cafe-mpc experiment NAME`` has one subparser per experiment built
from it (``NAME --help`` shows that experiment's options only) and hands the strings it got to
``parse_options``; ``run_experiment(name, ..., schedules="S0,S4")`` does the same with Python values. The
field types below turn the command line's text into values and check them, with one error line naming the
flag (``--schedules: unknown value 'S7'; known: S0, ...``):

* ``names(known)``: a comma-separated list of distinct names (``known``: the allowed ones, or a function
  giving them when asked);
* ``numbers(low, high, none_word=False)``: a comma-separated list of distinct numbers in ``[low, high]``
  (with ``none_word``, ``none`` is the empty list);
* ``integers(low)``: a comma-separated list of distinct integers ``>= low``;
* ``integer(low, high)``, ``number(low, high)``: one value in the range.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Annotated, Any, TypeVar

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, ValidationError

from cafe_mpc.config import ConfigError

Known = Sequence[str] | Callable[[], Sequence[str]]
"""The values a list option allows, or a function that gives them (evaluated when an option is parsed)."""


class ExperimentOptions(BaseModel):
    """Base of an experiment's options (none); a subclass adds one field per option."""

    model_config = ConfigDict(extra="forbid", frozen=True)


OptionsModel = TypeVar("OptionsModel", bound=ExperimentOptions)


def flag(name: str) -> str:
    """``srb_dts`` -> ``--srb-dts``."""
    return "--" + name.replace("_", "-")


def _items(value: Any) -> Any:
    """``"S0, S4"`` or ``["S0", "S4"]`` -> ``("S0", "S4")``; other values unchanged."""
    if isinstance(value, str):
        return tuple(item.strip() for item in value.split(",") if item.strip())
    if isinstance(value, list | tuple):
        return tuple(str(item).strip() for item in value if str(item).strip())
    return value


def _distinct(values: tuple) -> tuple:
    if not values:
        raise ValueError("give at least one value")
    if len(set(values)) != len(values):
        raise ValueError(f"repeated value in {','.join(str(v) for v in values)}")
    return values


def _one_of(known: Known | None) -> Callable[[tuple[str, ...]], tuple[str, ...]]:
    def check(values: tuple[str, ...]) -> tuple[str, ...]:
        _distinct(values)
        if known is not None:
            allowed = list(known() if callable(known) else known)
            for value in values:
                if value not in allowed:
                    raise ValueError(f"unknown value {value!r}; known: {', '.join(allowed)}")
        return values

    return check


def _parsed(kind: type, what: str) -> Callable[[Any], Any]:
    def parse(value: Any) -> Any:
        items = _items(value)
        if not isinstance(items, tuple):
            return items
        parsed = []
        for item in items:
            try:
                parsed.append(kind(item))
            except ValueError:
                raise ValueError(f"{item!r} is not {what}") from None
        return tuple(parsed)

    return parse


def _text(value: float) -> str:
    """An integer as written (``1000000``), a number in ``g`` format (``0.5``)."""
    return str(value) if isinstance(value, int) else f"{value:g}"


def _within(low: float, high: float | None) -> Callable[[Any], Any]:
    def check(value: Any) -> Any:
        for item in value if isinstance(value, tuple) else (value,):
            if item < low or (high is not None and item > high):
                bounds = f"[{_text(low)}, {_text(high)}]" if high is not None else f">= {_text(low)}"
                raise ValueError(f"{_text(item)} is outside {bounds}")
        return value

    return check


def names(known: Known | None = None) -> Any:
    """A comma-separated list of distinct names (of ``known``, when given)."""
    return Annotated[tuple[str, ...], BeforeValidator(_items), AfterValidator(_one_of(known))]


def numbers(low: float, high: float, none_word: bool = False) -> Any:
    """A comma-separated list of distinct numbers in ``[low, high]``; with ``none_word``, ``none`` (any case)
    is the empty list (a sweep to skip)."""

    def parse(value: Any) -> Any:
        if none_word and isinstance(value, str) and value.strip().lower() == "none":
            return ()
        return _parsed(float, "a number")(value)

    def check(values: tuple[float, ...]) -> tuple[float, ...]:
        if values or not none_word:
            _distinct(values)
        return _within(low, high)(values)

    return Annotated[tuple[float, ...], BeforeValidator(parse), AfterValidator(check)]


def integers(low: int) -> Any:
    """A comma-separated list of distinct integers ``>= low``."""
    return Annotated[
        tuple[int, ...],
        BeforeValidator(_parsed(int, "an integer")),
        AfterValidator(_distinct),
        AfterValidator(_within(low, None)),
    ]


def integer(low: int, high: int) -> Any:
    """One integer in ``[low, high]``."""
    return Annotated[int, AfterValidator(_within(low, high))]


def number(low: float, high: float) -> Any:
    """One number in ``[low, high]``."""
    return Annotated[float, AfterValidator(_within(low, high))]


def option_fields(model: type[ExperimentOptions]) -> list[tuple[str, str, str, str | None, bool]]:
    """``(dest, flag, help, metavar, is_flag)`` of every option of ``model``, in order."""
    fields = []
    for name, field in model.model_fields.items():
        extra = field.json_schema_extra if isinstance(field.json_schema_extra, dict) else {}
        metavar = extra.get("metavar")
        fields.append(
            (
                name,
                flag(name),
                field.description or "",
                str(metavar) if metavar else None,
                field.annotation is bool,
            )
        )
    return fields


def parse_options(model: type[OptionsModel], given: Mapping[str, Any], experiment: str) -> OptionsModel:
    """The options of experiment ``experiment`` from what was given (``None`` and ``False``: not given;
    strings as on the command line, or Python values); ``ConfigError`` with one line naming the flag."""
    chosen = {name: value for name, value in given.items() if value is not None and value is not False}
    own = model.model_fields
    for name in chosen:
        if name not in own:
            flags = ", ".join(flag(other) for other in own)
            raise ConfigError(
                f"{flag(name)} does not apply to experiment {experiment!r}"
                + (f" (it takes {flags})" if flags else "")
            )
    try:
        return model.model_validate(chosen)
    except ValidationError as error:
        lines = []
        for problem in error.errors():
            message = problem["msg"].removeprefix("Value error, ")
            if problem["loc"]:
                got = problem.get("input")
                detail = "" if problem["type"] == "value_error" else f" (got {got!r})"
                lines.append(f"{flag(str(problem['loc'][0]))}: {message}{detail}")
            else:
                lines.append(message)
        raise ConfigError("; ".join(lines)) from error
