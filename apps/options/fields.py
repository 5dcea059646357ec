"""The generator: options from a config dataclass's fields and their ``Attributes:`` docstring, and back."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import re
import typing
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from .attributes import field_docs, format_value, help_and_default


def option_dest(name: str, override: Mapping[str, Any] | None = None) -> str:
    """The namespace attribute of field ``name``'s option (``override["dest"]``, else the field name)."""
    return (override or {}).get("dest", name)


def _fields(cls: type) -> dict[str, dataclasses.Field]:
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    return {f.name: f for f in dataclasses.fields(cls)}


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def _scalar_type(cls: type, name: str) -> type | None:
    """int, float or bool when the field's annotation is that (or that | None); None for anything else."""
    try:
        hint = typing.get_type_hints(cls)[name]
    except Exception:  # noqa: BLE001 - an annotation that does not evaluate here is treated as text
        return None
    args = [a for a in typing.get_args(hint) if a is not type(None)] if typing.get_args(hint) else [hint]
    return args[0] if len(args) == 1 and args[0] in (int, float, bool) else None


def add_config_options(
    parser,
    cls: type,
    fields: Sequence[str],
    overrides: Mapping[str, Mapping] | None = None,
    presets: Mapping[str, Mapping[str, Any]] | None = None,
) -> list[argparse.Action]:
    """Add one option per field of the dataclass ``cls`` to ``parser`` (a parser or an argument group).

    Args:
        fields: the field names, in option order.
        overrides: per field, :meth:`~argparse.ArgumentParser.add_argument` keywords (``help``, ``metavar``,
            ``type``, ``choices``, ``dest``) and ``flags`` (the option strings; default ``--field-name``),
            ``default_text`` (what "(default: ...)" says, when the value alone would not say it), ``negate`` (a
            bool flag that sets the field to False, e.g. ``--no-fill``) and ``convert`` (text -> field value, for
            :func:`config_from_args`).
        presets: ``{label: {field: value}}``: a preset's value is shown next to the default ("0.05 with --quick").
    Returns:
        the added actions. A field without help (no override, no docstring entry) is a TypeError: the config's
        docstring must document it.
    """
    known, docs = _fields(cls), field_docs(cls)
    actions = []
    for name in fields:
        if name not in known:
            raise TypeError(f"{cls.__name__} has no field {name!r}")
        over = dict((overrides or {}).get(name, {}))
        flags = over.pop("flags", ("--" + name.replace("_", "-"),))
        text = over.pop("help", None)
        if text is None and not docs.get(name):
            raise TypeError(f"{cls.__name__}.{name} has no help: document it in the class's Attributes section")
        default = _default(known[name])
        doc_help, doc_default = help_and_default(docs.get(name, ""), default)
        text = doc_help if text is None else text
        shown = over.pop("default_text", None) or doc_default
        extra = [f"{format_value(p[name])} with {label}" for label, p in (presets or {}).items() if name in p]
        kind = _scalar_type(cls, name)
        negate = over.pop("negate", False)
        over.pop("convert", None)
        if kind is bool or negate:
            over.setdefault("action", "store_true")
        elif "type" not in over and kind in (int, float):
            over["type"] = kind
        over.setdefault("dest", name)
        if over.get("action") != "store_true" and "choices" not in over:  # the metavar argparse derives from a flag
            long = next((f for f in flags if f.startswith("--")), flags[0])
            over.setdefault("metavar", long.lstrip("-").replace("-", "_").upper())
        default_note = f"default: {shown}" + "".join(f"; {e}" for e in extra)
        actions.append(
            parser.add_argument(
                *flags,
                default=None if over.get("action") != "store_true" else False,
                help=f"{text} ({default_note})",
                **over,
            )
        )
    return actions


def config_values(
    cls: type, args: argparse.Namespace, fields: Sequence[str], overrides: Mapping[str, Mapping] | None = None
) -> dict[str, Any]:
    """``{field: value}`` of the options of ``fields`` that were given on the command line (None and unset
    flags are left out), converted by each override's ``convert``; a ValueError from it names the option."""
    values: dict[str, Any] = {}
    for name in fields:
        over = (overrides or {}).get(name, {})
        value = getattr(args, option_dest(name, over), None)
        if value is None or value is False:
            continue
        flag = over.get("flags", ("--" + name.replace("_", "-"),))[0]
        if over.get("negate"):
            value = False
        elif "convert" in over:
            convert: Callable[[Any], Any] = over["convert"]
            try:
                value = convert(value)
            except ValueError as exc:
                message = str(exc)
                raise ValueError(message if flag in message else f"{flag}: {message}") from None
        values[name] = value
    return values


def option_names(cls: type, fields: Sequence[str], overrides: Mapping[str, Mapping] | None = None) -> dict[str, str]:
    """``{"Class.field": "--flag"}``: the option the user writes for each field of ``fields``."""
    return {
        f"{cls.__name__}.{name}": (overrides or {}).get(name, {}).get("flags", ("--" + name.replace("_", "-"),))[0]
        for name in fields
    }


def rename_fields(message: str, names: Mapping[str, str]) -> str:
    """``message`` with every ``Class.field`` of ``names`` replaced by what the user wrote (an option, a key)."""
    for internal in sorted(names, key=len, reverse=True):
        message = re.sub(rf"\b{re.escape(internal)}\b", names[internal], message)
    return message


@contextlib.contextmanager
def options_named(names: Mapping[str, str]):
    """Re-raise a config's ValueError with its ``Class.field`` names replaced by the user's (:func:`rename_fields`)."""
    try:
        yield
    except ValueError as exc:
        message = rename_fields(str(exc), names)
        if message == str(exc):
            raise
        raise ValueError(message) from None


def config_from_args(
    cls: type,
    args: argparse.Namespace,
    fields: Sequence[str],
    overrides: Mapping[str, Mapping] | None = None,
    preset: Mapping[str, Any] | None = None,
    base: Any = None,
    **extra: Any,
):
    """The config of the command line: the dataclass defaults (or ``base``), then ``preset``, then the options of
    ``fields`` the user gave, then ``extra`` (values the command computes). The config validates itself."""
    values = {**(preset or {}), **config_values(cls, args, fields, overrides), **extra}
    with options_named(option_names(cls, fields, overrides)):
        return dataclasses.replace(base, **values) if base is not None else cls(**values)


def parse_list(text, item: Callable[[str], Any] = str, option: str = "the list", **checks):
    """The one comma-list parser (:func:`nbv.lists.parse_list`; imported on use, so ``--help`` loads nothing)."""
    from nbv.lists import parse_list as parse

    return parse(text, item, option, **checks)


def index_list(
    text: str | None, option: str, count: int | None = None, what: str | None = None, **hints: str
) -> tuple[int, ...]:
    """``"0,5"`` -> (0, 5): distinct indices >= 0 (below ``count`` when given); ValueError naming ``option``
    (``hints``: ``empty_hint``, ``range_hint`` of :func:`nbv.lists.parse_list`)."""
    return parse_list(text, int, option, minimum=0, below=count, unique=True, what=what, **hints)


def float_list(text: str, option: str, size: int | None = None) -> tuple[float, ...]:
    """``"1,0,0"`` -> (1.0, 0.0, 0.0): finite numbers (exactly ``size`` of them when given)."""
    return parse_list(text, float, option, size=size, what="number")
