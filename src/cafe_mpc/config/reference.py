"""The configuration reference, generated from the schema: every key of a run config with its type, default
and description (``docs/configuration.md``; ``cafe-mpc config --reference``).

The descriptions are the pydantic fields' ``description`` (a section without one takes the first sentence of
its model's docstring), so the reference cannot drift from the code: ``tests/test_config_reference.py`` fails
when ``docs/configuration.md`` is not the current output or when a key has no description
(``undocumented_keys``).
"""

from __future__ import annotations

import types
import typing
from dataclasses import dataclass
from typing import Any, Literal

from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from cafe_mpc.config.run import RunConfig

BEGIN_MARK = "<!-- BEGIN GENERATED REFERENCE (cafe-mpc config --reference; do not edit by hand) -->"
END_MARK = "<!-- END GENERATED REFERENCE -->"


@dataclass(frozen=True)
class ReferenceRow:
    """One key of the reference: dotted path (``[]`` marks a list element), type, default, description."""

    key: str
    type: str
    default: str
    description: str
    section: bool


def _section_model(annotation: Any) -> tuple[type[BaseModel] | None, bool]:
    """The model inside ``Model``, ``Model | None`` or ``list[Model]``, and whether it is a list's element."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation, False
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is list and args and isinstance(args[0], type) and issubclass(args[0], BaseModel):
        return args[0], True
    if origin in (typing.Union, types.UnionType):
        for arg in args:
            model, is_list = _section_model(arg)
            if model is not None:
                return model, is_list
    return None, False


def _type_name(annotation: Any) -> str:
    """A short, readable type: ``float``, ``float | null``, ``trot | pace``, ``list of 3 float``."""
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if annotation is type(None):
        return "null"
    if origin is Literal:
        return " \\| ".join(str(arg) for arg in args)
    if origin in (typing.Union, types.UnionType):
        return " \\| ".join(_type_name(arg) for arg in args)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {_type_name(args[0])}"
        if args and all(arg == args[0] for arg in args):
            return f"list of {len(args)} {_type_name(args[0])}"
        return "list of (" + ", ".join(_type_name(arg) for arg in args) + ")"
    if origin is list:
        return f"list of {_type_name(args[0])}" if args else "list"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "section"
    return getattr(annotation, "__name__", str(annotation))


def _default_text(value: Any) -> str:
    """A default as it would be written in YAML (short)."""
    if value is PydanticUndefined:
        return "required"
    if isinstance(value, BaseModel):
        return ""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, tuple | list):
        if value and all(isinstance(item, BaseModel) for item in value):
            return f"{len(value)} item(s)"
        return "[" + ", ".join(_default_text(item) for item in value) + "]"
    return str(value)


def _docstring_sentence(model: type[BaseModel]) -> str:
    """The first sentence of a model's docstring (one line), or ``""``."""
    doc = " ".join((model.__doc__ or "").split()).replace("``", "`")
    if not doc:
        return ""
    end = doc.find(". ")
    return doc if end < 0 else doc[: end + 1]


def _description(field: FieldInfo, model: type[BaseModel] | None) -> str:
    text = " ".join((field.description or "").split()).replace("``", "`")
    if not text and model is not None:
        text = _docstring_sentence(model)
    return text


def reference_rows(model: type[BaseModel] = RunConfig) -> list[ReferenceRow]:
    """Every key of ``model`` (sections, then their keys, in schema order) with its default in a default
    instance where the section has one (so that, e.g., ``costs.terminal`` shows the terminal set)."""
    rows: list[ReferenceRow] = []

    def walk(current: type[BaseModel], instance: BaseModel | None, prefix: str) -> None:
        for name, field in current.model_fields.items():
            key = f"{prefix}{name}"
            sub, is_list = _section_model(field.annotation)
            if instance is not None:
                value = getattr(instance, name)
            else:
                value = field.get_default(call_default_factory=True)
            if sub is not None:
                default = _default_text(value) if (value is None or is_list) else ""
                rows.append(
                    ReferenceRow(key, _type_name(field.annotation), default, _description(field, sub), True)
                )
                sub_instance = value if isinstance(value, BaseModel) else None
                if sub_instance is None and not is_list:
                    try:  # an optional section (gait: null): its keys' defaults when it is given
                        sub_instance = sub()
                    except ValueError:
                        sub_instance = None
                walk(sub, sub_instance, f"{key}[]." if is_list else f"{key}.")
            else:
                rows.append(
                    ReferenceRow(
                        key,
                        _type_name(field.annotation),
                        _default_text(value),
                        _description(field, None),
                        False,
                    )
                )

    walk(model, model(), "")
    return rows


def undocumented_keys(model: type[BaseModel] = RunConfig) -> list[str]:
    """Keys without a description (a test keeps this empty)."""
    return [row.key for row in reference_rows(model) if not row.description]


def reference_markdown(model: type[BaseModel] = RunConfig) -> str:
    """The reference as a markdown table between ``BEGIN_MARK`` and ``END_MARK``."""
    lines = [
        BEGIN_MARK,
        "",
        "| key | type | default | description |",
        "|---|---|---|---|",
    ]
    for row in reference_rows(model):
        key = f"**`{row.key}`**" if row.section else f"`{row.key}`"
        description = row.description.replace("|", "\\|")
        default = row.default.replace("|", "\\|")
        lines.append(f"| {key} | {row.type} | {default} | {description} |")
    lines += ["", END_MARK]
    return "\n".join(lines) + "\n"


def generated_block(text: str) -> str | None:
    """The generated block inside a document's text (``None`` when its markers are missing)."""
    start = text.find(BEGIN_MARK)
    end = text.find(END_MARK)
    if start < 0 or end < start:
        return None
    return text[start : end + len(END_MARK)] + "\n"


def update_document(text: str, model: type[BaseModel] = RunConfig) -> str:
    """``text`` with its generated block replaced by the current reference."""
    old = generated_block(text)
    if old is None:
        raise ValueError(f"the document has no generated block ({BEGIN_MARK} ... {END_MARK})")
    return text.replace(old, reference_markdown(model))
