"""Counts, steps, seeds, image widths and number lists of `fluidgs bench WHAT` and `demo` are refused when the options
are parsed (exit 2, one line naming the option), before a set is built, a seed overflows or a run starts."""

import argparse

import pytest

from apps import cli


@pytest.mark.parametrize(
    "argv, option",
    [
        (["views", "--count", "100000000000"], "--count"),  # a MemoryError traceback (800 GB asked of torch)
        (["views", "--views", "0"], "--views"),
        (["views", "--width", "0"], "--width"),  # a Camera's message, not the option's
        (["views", "--width", "100000000"], "--width"),
        (["views", "--render-width", "0"], "--render-width"),
        (["views", "--reference-views", "-1"], "--reference-views"),
        (["score", "--steps", "0"], "--steps"),  # ran the default 300 steps silently
        (["score", "--particle-radius", "0"], "--particle-radius"),
        (["probes", "--tolerances", "x"], "--tolerances"),  # ran the whole profile, then failed
        (["probes", "--tolerances", "nan"], "--tolerances"),
        (["probes", "--fixed", "300,x"], "--fixed"),
        (["probes", "--steps", "0"], "--steps"),
        (["sim", "--steps", "10000000"], "--steps"),  # unbounded
        (["sim", "--rounds", "100000000"], "--rounds"),  # unbounded
        (["render", "--seed", "100000000000000000000"], "--seed"),  # "Overflow when unpacking long long"
        (["render", "--seed", "-1"], "--seed"),
    ],
)
def test_bench_numbers_are_bounded_when_parsed(argv, option, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["bench", *argv])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"argument {option}" in err and "must be" in err, err
    assert "Traceback" not in err and "Camera" not in err


def test_bench_number_types_keep_the_defaults():
    args = cli.build_parser("bench").parse_args(["bench", "probes"])
    assert args.tolerances == (0.005, 0.01, 0.02, 0.03, 0.05) and args.fixed == (300, 400, 500, 600)
    assert cli.build_parser("bench").parse_args(["bench", "probes", "--fixed", ""]).fixed == ()


def test_demo_render_width_is_named_when_out_of_range(tmp_path, capsys):
    """`demo --render-width 0` said "scale factor must be > 0", 10^8 spoke of a Camera 'r_000'."""
    for width in ("0", "100000000"):
        with pytest.raises(SystemExit) as exc:
            cli.main(["demo", "-o", str(tmp_path / "d"), "--render-width", width])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and "argument --render-width: must be an integer from 1 to 65,536" in err, err
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("command", ["make-assets", "render-dataset"])
@pytest.mark.parametrize("value", ["100000000000000000000", "-1"])
def test_seeds_are_bounded_when_parsed(command, value, tmp_path, capsys):
    """`make-assets --seed` was a plain int (10^20 refused by the training config, after the option was taken);
    `render-dataset --seed 10^20` rendered a whole dataset. Both are refused when parsed, as the bench seeds are."""
    argv = [command, *([str(tmp_path / "mesh.obj")] if command == "render-dataset" else []), "-o", str(tmp_path / "a")]
    with pytest.raises(SystemExit) as exc:
        cli.main([*argv, "--seed", value])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "argument --seed: must be an integer from 0 to 4,294,967,295" in err, err
    assert not (tmp_path / "a").exists()


def test_every_seed_option_of_these_commands_has_the_bounded_type():
    from apps.options.numbers import seed

    for command in (("make-assets",), ("render-dataset",), ("bench", "render"), ("bench", "score"), ("bench", "views")):
        parser = cli.build_parser(command[0])
        for name in command:
            parser = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[name]
        (action,) = [a for a in parser._actions if "--seed" in a.option_strings]
        assert action.type is seed, command


@pytest.mark.parametrize("command", [["experiment"], ["study", "oracle"]])
def test_workers_are_bounded_when_parsed(command, tmp_path, capsys):
    """`--workers 10^20` was taken: the pool starts min(workers, jobs) processes, up to 10,000 (the planned jobs),
    each with its own torch and Taichi."""
    with pytest.raises(SystemExit) as exc:
        cli.main([*command, str(tmp_path / "config.json"), "--workers", "100000000000000000000"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "argument --workers: must be an integer from 1 to 1,024" in err, err


def test_a_particle_radius_whose_estimator_radius_overflows_names_the_option(tmp_path, caplog):
    """`active --particle-radius 1e308` (and eval's) said "estimator_radius must be a finite number, got inf": a
    solver field derived from r (4 r), which no option sets."""
    from nbv.physics import PhysicsConfig

    with pytest.raises(ValueError, match=r"^PhysicsConfig\.particle_radius must be .*got 1e\+308"):
        PhysicsConfig(particle_radius=1e308)
    with pytest.raises(ValueError, match="estimator_radius"):  # given explicitly, it is the one named
        PhysicsConfig(solver={"estimator_radius": float("inf")})
    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "transforms_train.json").write_text("{}")
    assert cli.main(["active", str(ds), "-o", str(tmp_path / "run"), "--particle-radius", "1e308"]) == 2
    assert "--particle-radius must be" in caplog.text and "estimator_radius" not in caplog.text
