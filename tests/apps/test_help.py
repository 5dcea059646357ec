"""Every `fluidgs` option's --help states its default once; required options state none."""

import argparse

from apps import bench, cli
from apps.help_format import HelpFormatter


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _option_help(parser: argparse.ArgumentParser) -> dict[str, str]:
    fmt = parser._get_formatter()
    return {
        a.dest: fmt._get_help_string(a)
        for a in parser._actions
        if a.option_strings and not isinstance(a, argparse._HelpAction)
    }


def test_every_option_of_every_command_states_its_default_once():
    commands = _subparsers(cli.build_parser())
    assert set(commands) == set(cli.COMMANDS)
    for name, parser in commands.items():
        for dest, text in _option_help(parser).items():
            action = next(a for a in parser._actions if a.dest == dest)
            where = f"fluidgs {name} {action.option_strings[-1]}"
            if action.required:
                assert "(default:" not in text, where  # no "(default: None)" on a required option
            else:
                assert text.replace("%(default)s", "").lower().count("default") == 1, f"{where}: {text!r}"


def test_formatter_appends_a_default_only_where_missing():
    p = argparse.ArgumentParser(formatter_class=HelpFormatter)
    p.add_argument("--a", type=int, default=3, help="step count")
    p.add_argument("--b", type=int, default=None, help="cap (default: none)")
    p.add_argument("-o", required=True, help="output file")
    text = p.format_help()
    assert "step count (default: 3)" in text
    assert "cap (default: none)" in text and "(default: None)" not in text


def test_bench_subcommands_are_registered():
    assert {"sim", "render", "score"} <= set(bench.BENCHMARKS)
