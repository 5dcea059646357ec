"""One smoke test over every `fluidgs` command, derived from the CLI's own parser (a new command is covered without
editing this file): each `--help` exits 0 and states a default for every option that takes a value, and each
command given a tiny bad input exits 2 with a message that names that input.

Everything runs in-process through :func:`apps.cli.main` (a subprocess per command costs seconds of imports each).
"""

from __future__ import annotations

import argparse
import logging
import re
import signal
from pathlib import Path

import pytest

from apps import cli

BAD_CONTENT = "not a valid input\n"
NOT_A_NUMBER = "not-a-number"
BAD_INPUT_SECONDS = 20  # a bad input is refused before any work; longer means it was not refused


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _walk(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, parser) of the root, every command and every subcommand (``bench sim``), depth first."""
    yield path, parser
    for name, sub in _subparsers(parser).items():
        yield from _walk(sub, (*path, name))


PARSERS = dict(_walk(cli.build_parser()))
COMMANDS = [path for path, parser in PARSERS.items() if path and not _subparsers(parser)]  # what runs


def _id(path: tuple[str, ...]) -> str:
    return " ".join(path) or "fluidgs"


def _options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [
        a
        for a in parser._actions
        if a.option_strings and not isinstance(a, argparse._HelpAction) and a.help != argparse.SUPPRESS
    ]


def _help_blocks(text: str) -> dict[str, str]:
    """Option string -> the help text printed for it (``--steps`` -> "steps of the probe (default: 750)"); the
    invocation starts a block at a small indent, its help follows on the same line or on deeper-indented lines."""
    blocks: dict[str, list[str]] = {}
    current: list[str] | None = None
    for line in text.splitlines():
        stripped = line.lstrip()
        indent = len(line) - len(stripped)
        if stripped.startswith("-") and indent <= 6:
            invocation, rest = re.match(r"(\S.*?)(?:\s{2,}(.*))?$", stripped).groups()
            current = [rest or ""]
            for part in invocation.split(", "):
                blocks[part.split(" ")[0].split("=")[0]] = current
        elif current is not None and stripped and indent > 6:
            current.append(stripped)
        else:
            current = None
    return {k: " ".join(v) for k, v in blocks.items()}


def _run(argv: list[str]) -> int:
    """``fluidgs ARGV`` in-process: the exit code, whether main returns it or argparse raises SystemExit."""
    try:
        return int(cli.main(argv) or 0)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 2


def test_version_prints_the_installed_version(capsys):
    from importlib.metadata import version

    assert _run(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"fluidgs {version('fluidgaussian')}"


def test_the_walk_reaches_every_registered_command():
    assert {path[0] for path in PARSERS if path} == set(cli.COMMANDS)
    assert len(COMMANDS) >= len(cli.COMMANDS)  # bench counts once per benchmark


@pytest.mark.parametrize("path", list(PARSERS), ids=_id)
def test_help_exits_0_and_states_every_default(path, capsys):
    assert _run([*path, "--help"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("usage: fluidgs"), text[:200]
    blocks = _help_blocks(text)
    for action in _options(PARSERS[path]):
        where = f"fluidgs {_id(path)} {action.option_strings[-1]}"
        block = next((blocks[o] for o in action.option_strings if o in blocks), None)
        assert block is not None, f"{where} is not in --help:\n{text}"
        if action.nargs == 0 or action.required:  # a flag (off unless given) or an option that must be given
            continue
        assert "default" in block.lower(), f"{where}: its help states no default: {block!r}"


class _TookTooLong(BaseException):  # not an Exception: the CLI's handlers must not turn it into an exit code
    pass


OUTPUT_KINDS = {
    r"\.(h5|hdf5)\b|\bHDF5\b": ".h5",
    r"\.json\b|\bJSON\b": ".json",
    r"\.csv\b|\bCSV\b": ".csv",
    r"\.ply\b": ".ply",
    r"\.mp4\b": ".mp4",
    r"\.obj\b": ".obj",
    r"\b(folder|directory)\b": "",
}


def _output_path(action: argparse.Action, folder: Path) -> str:
    """An output path of the kind that ``action``'s help names first ("output HDF5 file" -> out.h5, "run folder
    (config.json, ...)" -> out); a plain name when it names none."""
    text = action.help or ""
    found = [(m.start(), ext) for pattern, ext in OUTPUT_KINDS.items() for m in [re.search(pattern, text)] if m]
    return str(folder / f"out{min(found)[1] if found else ''}")


def _is_output(action: argparse.Action) -> bool:
    return action.dest in ("output", "json") or "-o" in action.option_strings


def _is_number_type(kind) -> bool:
    """int, float, or a bounded number of apps.options.numbers (a step count, a seed, ``int_in(1, 10)``)."""
    return kind in (int, float) or getattr(kind, "__module__", None) == "apps.options.numbers"


def _bad_argv(path: tuple[str, ...], parser: argparse.ArgumentParser, folder: Path) -> tuple[list[str], list[str]]:
    """(argv, the names a refusal must mention). Every input (positional, or required option other than the output)
    is a small file of text; a command without such inputs gets one for its first optional input path; one without
    any input path gets a non-number for its first numeric option (an argparse usage error). Outputs go to
    ``folder``, so that nothing is written into the working tree even if the input were accepted."""
    argv, names = list(path), []

    def bad_file(action: argparse.Action) -> str:
        f = folder / f"bad_{action.dest}.txt"
        f.write_text(BAD_CONTENT)
        names.append(f.name)
        return str(f)

    actions = [a for a in parser._actions if not isinstance(a, argparse._HelpAction)]
    for a in actions:
        if not a.option_strings:
            argv.append(bad_file(a))
        elif _is_output(a):
            if a.required or a.dest == "output":
                argv += [a.option_strings[-1], _output_path(a, folder)]
        elif a.required:
            argv += [a.option_strings[-1], bad_file(a)]
    if names:
        return argv, names
    optional_paths = [a for a in actions if a.option_strings and a.type is Path and not _is_output(a)]
    if optional_paths:
        a = optional_paths[0]
        return argv + [a.option_strings[-1], bad_file(a)], names
    numeric = [a for a in actions if a.option_strings and a.nargs is None and _is_number_type(a.type)]
    assert numeric, f"fluidgs {_id(path)}: no input to make bad; teach _bad_argv about this command"
    a = numeric[0]
    return argv + [f"{a.option_strings[-1]}={NOT_A_NUMBER}"], [a.option_strings[-1]]


@pytest.mark.parametrize("path", COMMANDS, ids=_id)
def test_bad_input_exits_2_naming_it(path, tmp_path, capsys, caplog):
    argv, names = _bad_argv(path, PARSERS[path], tmp_path)

    def took_too_long(signum, frame):
        raise _TookTooLong(f"fluidgs {' '.join(argv)} ran over {BAD_INPUT_SECONDS} s: the bad input was not refused")

    previous = signal.signal(signal.SIGALRM, took_too_long)
    signal.alarm(BAD_INPUT_SECONDS)
    try:
        with caplog.at_level(logging.ERROR):
            code = _run(argv)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    err = capsys.readouterr().err
    message = " ".join([err, *(r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR)])
    assert code == 2, f"fluidgs {' '.join(argv)} exited {code}: {message}"
    assert any(n in message for n in names), f"the message names none of {names}: {message!r}"
    assert "Traceback" not in message
