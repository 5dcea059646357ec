"""A config dataclass's ``Attributes:`` docstring section read as option help: ``{field: text}``, the text made
plain, and a default written as ``--help`` shows it."""

from __future__ import annotations

import functools
import re
from typing import Any

_ENTRY = re.compile(r"^(\s*)([A-Za-z_][\w, ]*?):\s*(.*)$")


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """``{field: text}`` from the ``Attributes:`` sections of ``cls`` and its bases (``a, b: text`` documents
    both; continuation lines are joined). Fields without an entry are missing from the result."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        docs.update(_attribute_section(klass.__doc__ or ""))
    return docs


def _attribute_section(doc: str) -> dict[str, str]:
    out: dict[str, str] = {}
    lines = doc.expandtabs().splitlines()
    start = next((i for i, line in enumerate(lines) if line.strip() == "Attributes:"), None)
    if start is None:
        return out
    names: list[str] = []
    indent = None
    for line in lines[start + 1 :]:
        if not line.strip():
            continue
        depth = len(line) - len(line.lstrip())
        match = _ENTRY.match(line)
        if indent is None:
            indent = depth
        if depth < indent:
            break  # the section ended
        if depth == indent and match:
            names = [n.strip() for n in match.group(2).split(",")]
            for n in names:
                out[n] = match.group(3).strip()
        elif depth > indent and names:
            for n in names:
                out[n] = f"{out[n]} {line.strip()}"
    return out


_ROLE = re.compile(r":\w+:`~?([^`]+)`")
_NONE_CLAUSE = re.compile(r"\s*[(;,]\s*None:\s*([^)]*?)\)?\.?$")


def plain(text: str) -> str:
    """A docstring fragment as help text: Sphinx roles and double back-quotes dropped, the end's period dropped."""
    return _ROLE.sub(r"\1", text).replace("``", "").strip().rstrip(".")


def help_and_default(text: str, default: Any) -> tuple[str, str]:
    """(help, default text) of a field: a trailing "(None: what happens)" clause of a field whose default is None
    becomes the default text ("(None: the available memory)" -> "default: the available memory")."""
    text = plain(text)
    match = _NONE_CLAUSE.search(text) if default is None else None
    if match:
        return text[: match.start()].rstrip(" ,;"), match.group(1).strip().rstrip(".")
    return text, format_value(default)


def format_value(value: Any) -> str:
    """A default as ``--help`` shows it: tuples as comma lists, None as "none"."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, (tuple, list)):
        return ",".join(format_value(v) for v in value)
    return str(value)
