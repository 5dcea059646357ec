"""The command line itself, read from the parsers' own actions: which options take a value, and whether every
argument can be recorded as UTF-8 text."""

from __future__ import annotations

import argparse
import os


def value_options(parser: argparse.ArgumentParser) -> tuple[frozenset[str], frozenset[str]]:
    """(the option strings that take one value, every option string) of ``parser`` and of all its subparsers, read
    from the argparse actions (the options themselves are the one list)."""
    takes, every = set(), set()
    stack = [parser]
    while stack:
        p = stack.pop()
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                stack.extend(action.choices.values())
                continue
            every.update(action.option_strings)
            if action.option_strings and action.nargs in (None, "?"):
                takes.update(action.option_strings)
    return frozenset(takes), frozenset(every)


def non_utf8_argument(parser: argparse.ArgumentParser, args: argparse.Namespace) -> str | None:
    """The message for the first argument of the command line that is not valid UTF-8 (a file name of other bytes,
    which Python keeps as surrogates), naming its option; None when every argument is. The results record file
    names as text (RESULT.h5's source, scores.json), which such a name cannot be written into."""
    stack = [parser]
    while stack:
        p = stack.pop()
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                stack.extend(c for name, c in action.choices.items() if name == getattr(args, "command", None))
                continue
            value = getattr(args, action.dest, None)
            for v in value if isinstance(value, (list, tuple)) else [value]:
                if not isinstance(v, (str, os.PathLike)):
                    continue
                try:
                    os.fspath(v).encode("utf-8")
                except UnicodeEncodeError:
                    name = (
                        action.option_strings[-1] if action.option_strings else (action.metavar or action.dest.upper())
                    )
                    raw = os.fsencode(v)
                    return (
                        f"{name} {raw!r}: the name is not valid UTF-8, and the outputs record file names as UTF-8 "
                        "text; rename the file (or folder) to a UTF-8 name and run again"
                    )
    return None


def join_dash_tokens(argv: list[str], parser: argparse.ArgumentParser) -> list[str]:
    """One rule for values that start with '-' (a probe "-x", a probe list "-x,+x", an up "-y", a box
    "-1,-1,-1,1,1,1", a vector "-0.1,1,0"): argparse would read such a value as an option, so ``--opt -x`` becomes
    ``--opt=-x`` for every option of ``parser`` that takes one value, unless the next token is itself an option of
    the parser (``--cameras -o out.json`` still says that --cameras lacks its value) or starts with ``--``. Tokens
    after a bare ``--`` are left alone.

    Args:
        argv: the command line without the program name.
        parser: the parser the line is for.
    """
    takes, every = value_options(parser)
    out: list[str] = []
    i = 0
    while i < len(argv):
        tok = argv[i]
        if tok == "--":
            return out + argv[i:]
        nxt = argv[i + 1] if i + 1 < len(argv) else None
        if (
            tok in takes
            and nxt is not None
            and nxt.startswith("-")
            and len(nxt) > 1
            and not nxt.startswith("--")
            and nxt not in every
            and nxt[:2] not in every
        ):
            out.append(f"{tok}={nxt}")
            i += 2
            continue
        out.append(tok)
        i += 1
    return out
