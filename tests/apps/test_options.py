"""One source for defaults (issue 16 item 5): options generated from the config dataclasses (apps/options/), the
one comma-list parser (nbv/lists.py) and the probe names defined once (fluidsim/directions.py)."""

import argparse
import dataclasses
import re
import subprocess
import sys

import pytest

from apps import cli
from apps.options import (
    add_config_options,
    config_from_args,
    config_values,
    field_docs,
    float_list,
    help_and_default,
    index_list,
)
from nbv.lists import parse_list

from helpers.paths import REPO as ROOT


@dataclasses.dataclass(frozen=True)
class Toy:
    """A config for the tests.

    Attributes:
        radius: particle radius r, m.
        steps: time steps per probe.
        lo, hi: the range, ``m`` (both
            ends included).
        cap: the largest count (None: no cap).
        fill: fill the solid.
        names: the probes, a tuple.
    """

    radius: float = 0.025
    steps: int = 750
    lo: float = 0.0
    hi: float = 1.0
    cap: int | None = None
    fill: bool = True
    names: tuple[str, ...] = ("a", "b")


def _parser(fields=("radius", "steps", "cap"), overrides=None, presets=None):
    p = argparse.ArgumentParser()
    add_config_options(p, Toy, fields, overrides, presets)
    return p


def _help(parser, dest):
    action = next(a for a in parser._actions if a.dest == dest)
    return action.help


def test_field_docs_reads_the_attributes_section():
    docs = field_docs(Toy)
    assert docs["radius"] == "particle radius r, m."
    assert docs["lo"] == docs["hi"] == "the range, ``m`` (both ends included)."  # two names, a continuation line
    from recon.train import TrainConfig

    train = field_docs(TrainConfig)
    assert train["position_lr_final"] == train["position_lr_init"] and "learning rates" in train["position_lr_init"]
    assert "seed" in train and "adam_eps" in train  # the last entry of the section


def test_help_is_the_docstring_with_the_dataclass_default_and_the_presets():
    p = _parser(presets={"--quick": {"radius": 0.05}})
    assert _help(p, "radius") == "particle radius r, m (default: 0.025; 0.05 with --quick)"
    assert _help(p, "steps") == "time steps per probe (default: 750)"
    assert _help(p, "cap") == "the largest count (default: no cap)"  # the "(None: ...)" clause names the default
    assert help_and_default("the range, ``m``.", (1, 2)) == ("the range, m", "1,2")


def test_a_changed_dataclass_default_changes_the_help_and_the_parsed_config():
    Moved = dataclasses.make_dataclass("Moved", [("radius", float, dataclasses.field(default=0.04))], frozen=True)
    Moved.__doc__ = Toy.__doc__
    p = argparse.ArgumentParser()
    add_config_options(p, Moved, ("radius",))
    assert "(default: 0.04)" in _help(p, "radius")
    assert config_from_args(Moved, p.parse_args([]), ("radius",)).radius == 0.04


def test_config_from_args_takes_only_the_given_options_over_the_preset():
    p = _parser(presets={"--quick": {"radius": 0.05, "steps": 300}})
    args = p.parse_args(["--steps", "40"])
    assert args.radius is None and args.steps == 40  # not given: None, so a preset can still apply
    assert config_values(Toy, args, ("radius", "steps", "cap")) == {"steps": 40}
    assert config_from_args(Toy, args, ("radius", "steps")) == Toy(steps=40)
    quick = config_from_args(Toy, args, ("radius", "steps"), preset={"radius": 0.05, "steps": 300})
    assert (quick.radius, quick.steps) == (0.05, 40)  # the explicit option wins over the preset
    assert isinstance(p.parse_args(["--radius", "0.1"]).radius, float)
    with pytest.raises(SystemExit):
        p.parse_args(["--steps", "1.5"])  # typed from the annotation: int


def test_flags_renames_negation_and_convert():
    over = {
        "fill": {
            "flags": ("--no-fill",),
            "dest": "no_fill",
            "negate": True,
            "default_text": "filled",
            "help": "keep the solid hollow",
        },
        "names": {"flags": ("--probes",), "convert": lambda t: tuple(parse_list(t, str, "--probes"))},
    }
    p = _parser(("fill", "names"), over)
    assert _help(p, "no_fill") == "keep the solid hollow (default: filled)"
    assert _help(p, "names") == "the probes, a tuple (default: a,b)"
    assert config_from_args(Toy, p.parse_args([]), ("fill", "names"), over) == Toy()
    cfg = config_from_args(Toy, p.parse_args(["--no-fill", "--probes", "x, y"]), ("fill", "names"), over)
    assert cfg.fill is False and cfg.names == ("x", "y")
    over["names"]["convert"] = lambda t: index_list(t, "--probes")
    with pytest.raises(ValueError, match="--probes must be a comma list of integers"):
        config_from_args(Toy, p.parse_args(["--probes", "x"]), ("names",), over)


def test_an_undocumented_field_or_a_wrong_name_is_refused():
    Bare = dataclasses.make_dataclass("Bare", [("a", int, dataclasses.field(default=1))])
    Bare.__doc__ = "No attributes."
    with pytest.raises(TypeError, match="Bare.a has no help"):
        add_config_options(argparse.ArgumentParser(), Bare, ("a",))
    with pytest.raises(TypeError, match="has no field 'nope'"):
        add_config_options(argparse.ArgumentParser(), Toy, ("nope",))


def _subparser(name):
    for action in cli.build_parser(name)._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices[name]


def test_simulate_help_shows_the_physics_config_defaults():
    from nbv.physics import QUICK, PhysicsConfig

    p = _subparser("simulate")
    default = PhysicsConfig()
    for name in ("particle_radius", "steps", "dt", "speed", "viscosity", "accumulate_every", "opacity_threshold"):
        text = _help(p, name)
        assert f"(default: {getattr(default, name)}" in text, (name, text)
        if name in QUICK:
            assert f"; {QUICK[name]} with --quick)" in text, (name, text)
    args = p.parse_args(["g.ply", "-o", "r.h5", "--quick", "--steps", "20"])
    from apps.options import physics_config_from_args

    cfg = physics_config_from_args(args)
    assert (cfg.particle_radius, cfg.steps, cfg.dt) == (QUICK["particle_radius"], 20, default.dt)


def test_active_help_shows_each_preset_value():
    from nbv.active import PRESETS

    small = PRESETS["cpu-small"]
    p = _subparser("active")
    assert _help(p, "iters_per_view").endswith(
        f"(default: 100; {small['iterations_per_view']} with --preset cpu-small)"
    )
    assert f"{small['physics']['steps']} with --preset cpu-small" in _help(p, "probe_steps")
    assert f"{small['train']['max_gaussians']} with --preset cpu-small" in _help(p, "max_gaussians")


def test_parse_list_checks_and_names_the_option():
    assert parse_list("3, 4,50", float, "--velocities", positive=True) == (3.0, 4.0, 50.0)
    assert parse_list(["-x", "+z"], str, "--directions", allowed=("-x", "+z")) == ("-x", "+z")
    assert index_list("4, 2,", "--candidates", 6) == (4, 2)
    assert float_list("1,0,-0.5", "--initial-direction", size=3) == (1.0, 0.0, -0.5)
    cases = [
        (
            lambda: parse_list("3,-1", float, "--velocities", positive=True, what="speed"),
            r"--velocities must be speeds > 0, got \[3.0, -1.0\]",
        ),
        (lambda: parse_list("1,nan", float, "--v"), "must be finite"),
        (lambda: float_list("1,0", "--initial-direction", size=3), "must be 3 comma-separated numbers"),
        (lambda: index_list(" , ", "--views"), "lists no entry"),
        (lambda: index_list("0,7", "--views", 6, range_hint="the split has 6"), r"\[7\] out of range: the split"),
        (lambda: index_list("-1", "--views"), "indices start at 0"),
        (lambda: index_list("2,2", "--c", what="camera"), r"lists camera\(s\) \[2\] more than once"),
        (
            lambda: parse_list("-x,-q", str, "--directions", allowed=("-x",), what="probe"),
            r"--directions: unknown probes \['-q'\]; use a comma list of -x",
        ),
    ]
    for call, message in cases:
        with pytest.raises(ValueError, match=message):
            call()


def test_directions_are_defined_once():
    """The five probe names are spelled out in fluidsim/directions.py only; every other module imports them."""
    spelled = re.compile(r"""["']-x["'],\s*["']\+x["'],\s*["']-z["'],\s*["']\+z["'],\s*["']-y["']""")
    found = [
        str(f.relative_to(ROOT))
        for pkg in ("fluidsim", "recon", "nbv", "viz", "apps")
        for f in sorted((ROOT / pkg).rglob("*.py"))
        if spelled.search(f.read_text())
    ]
    assert found == ["fluidsim/directions.py"]


def test_names_and_top_level_help_load_no_engine():
    """viz and `fluidgs --help` read the probe names and list the commands without Taichi or torch."""
    code = (
        "import sys\nfrom fluidsim.directions import DIRECTIONS\nimport viz.data\nfrom apps import cli\n"
        "cli.build_parser('')\n"
        "print(sorted(m for m in ('taichi', 'torch', 'nbv') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "[]"
