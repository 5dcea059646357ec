"""One rule for values that start with '-': every option of every `fluidgs` parser that takes a value reads
`--opt -x` exactly as `--opt=-x` (the set of options comes from the parsers themselves,
apps.options.argv.value_options)."""

import argparse
import contextlib
import io

import pytest

from apps import cli
from apps.options.argv import value_options


def _parsers(parser: argparse.ArgumentParser, path=()):
    """(command path, parser) of every parser under ``parser``, nested subcommands included."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, parser
    for action in subs:
        for name, sub in action.choices.items():
            yield from _parsers(sub, (*path, name))


def _relaxed(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The parser with nothing required (test-only: every parser here is built fresh), so one option parses alone."""
    for a in parser._actions:
        a.required = False
        if not a.option_strings and a.nargs is None:
            a.nargs = "?"
    return parser


def _outcome(parser, argv):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            return "ok", vars(parser.parse_args(argv))
        except SystemExit:
            return "error", err.getvalue().strip().splitlines()[-1]


def test_every_value_option_of_every_parser_takes_a_dash_value_both_ways():
    root = cli.build_parser()
    checked = 0
    for path, parser in _parsers(root):
        takes, every = value_options(parser)
        assert takes <= every
        parser = _relaxed(parser)
        for action in parser._actions:
            if not action.option_strings or action.nargs not in (None, "?") or isinstance(action, argparse._HelpAction):
                continue
            for flag in action.option_strings:
                assert flag in takes, (path, flag)
                spaced = cli.join_dash_values([flag, "-x"], parser)
                assert spaced == [f"{flag}=-x"], (path, flag)
                with_space, with_equals = _outcome(parser, spaced), _outcome(parser, [f"{flag}=-x"])
                assert with_space == with_equals, (path, flag)
                assert "expected one argument" not in str(with_space), (path, flag)
                checked += 1
    assert checked > 200  # every command's options were walked


@pytest.mark.parametrize(
    "argv, dest, value",
    [
        (["simulate", "g.ply", "-o", "r.h5", "--video", "-x"], "video", "-x"),
        (["simulate", "g.ply", "-o", "r.h5", "--directions", "-x,+x"], "directions", "-x,+x"),
        (["simulate", "g.ply", "-o", "r.h5", "--directions=-x,+x"], "directions", "-x,+x"),
        (["score", "g.ply", "--cameras", "orbit:4", "-o", "s.json", "--metric", "-x"], "metric", "-x"),
        (["score", "g.ply", "--cameras", "orbit:4", "-o", "s.json", "--elevations", "-10,20"], "elevations", "-10,20"),
        (["critical", "g.ply", "--cameras", "c.json", "--up", "-y"], "up", "-y"),
        (["inspect", "g.ply", "--crop", "-1,-1,-1,1,1,1"], "crop", "-1,-1,-1,1,1,1"),
        (["simulate", "g.ply", "-o", "r.h5", "--record-probe", "-x"], "record_probe", "-x"),
    ],
)
def test_the_issues_examples(argv, dest, value):
    parser = cli.build_parser(cli.command_of(argv))
    assert getattr(parser.parse_args(cli.join_dash_values(argv, parser)), dest) == value


def test_an_option_as_the_next_token_is_still_a_missing_value():
    argv = ["score", "g.ply", "--cameras", "-o", "s.json"]
    parser = cli.build_parser("score")
    assert cli.join_dash_values(argv, parser) == argv
    assert cli.join_dash_values(["simulate", "g.ply", "--ply", "--quick"]) == ["simulate", "g.ply", "--ply", "--quick"]
    assert cli.join_dash_values(["--", "--up", "-y"]) == ["--", "--up", "-y"]
