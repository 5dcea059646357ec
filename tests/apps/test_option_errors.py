"""Config errors speak of the command-line options the user wrote (--scale, --budget), never of the config classes'
fields."""

import pytest

from apps import cli

from helpers.logs import error_text


def test_config_errors_name_the_option_not_the_class(tmp_path, caplog):
    """`PhysicsConfig.scale` and `ActiveConfig.budget` appeared where the user wrote --scale and --budget."""
    (tmp_path / "ds").mkdir()
    assert cli.main(["simulate", "g.ply", "-o", str(tmp_path / "r.h5"), "--scale", "0"]) == 2
    assert cli.main(["active", str(tmp_path / "ds"), "-o", str(tmp_path / "run"), "--budget", "0"]) == 2
    assert cli.main(["active", str(tmp_path / "ds"), "-o", str(tmp_path / "run"), "--probe-steps", "0"]) == 2
    msg = error_text(caplog)
    assert "--scale must be 'auto' or a number > 0" in msg and "--budget must be an integer >= 1" in msg
    assert "--probe-steps must be an integer >= 1" in msg and "Config." not in msg


@pytest.mark.parametrize("command", ["simulate", "critical", "compare"])
def test_accumulating_less_often_than_once_per_probe_is_refused(command, tmp_path, caplog):
    """--accumulate-every above --steps accumulated no step: the whole run gave D_g = 0 everywhere and a warning to
    check the time step, the scale and the up direction. It is refused before any work, naming the option."""
    out = (
        ["--cameras", "orbit:4"] if command == "critical" else ["--reference", "g.ply"] if command == "compare" else []
    )
    args = [command, "g.ply", "-o", str(tmp_path / "r.json"), *out, "--steps", "20", "--accumulate-every", "21"]
    assert cli.main(args) == 2
    assert "--accumulate-every must be at most the 20 steps per probe, got 21" in error_text(caplog)


def test_rename_fields_replaces_whole_names_only():
    from apps.options import option_names
    from apps.options.fields import rename_fields
    from nbv.physics import PhysicsConfig

    names = option_names(PhysicsConfig, ("steps", "fill_cavities"), {"fill_cavities": {"flags": ("--no-fill",)}})
    assert names == {"PhysicsConfig.steps": "--steps", "PhysicsConfig.fill_cavities": "--no-fill"}
    assert rename_fields("PhysicsConfig.steps and PhysicsConfig.steps_x", names) == "--steps and PhysicsConfig.steps_x"


def test_training_counts_are_bounded_and_named_as_options(tmp_path, caplog):
    """train --init-points 10^12 was a torch allocation traceback, --iters 10^14 and active --iterations 10^14 ran
    for ever, --seed 10^20 said 'Overflow when unpacking long long', --up 0,0,0 spoke of ActiveConfig.up, and
    make-assets spoke of TrainConfig and MeshDatasetConfig; each is refused up front, naming the option (a seed of
    make-assets or render-dataset when parsed: test_number_limits)."""
    ds, ply = str(tmp_path / "ds"), str(tmp_path / "o.ply")
    cases = [
        (["train", ds, "-o", ply, "--iters", "99999999999999"], "--iters must be at most 1,000,000"),
        (["train", ds, "-o", ply, "--init-points", "1000000000000"], "--init-points must be at most 10,000,000"),
        (["train", ds, "-o", ply, "--seed", "99999999999999999999"], "--seed must be at most 4,294,967,295"),
        (["train", ds, "-o", ply, "--res", "10000000"], "--res must be a width in pixels from 1 to 65,536"),
        (["active", ds, "-o", str(tmp_path / "run"), "--iterations", "99999999999999"], "--iterations must be at most"),
        (["active", ds, "-o", str(tmp_path / "run"), "--res", "100000000"], "--res must be at most 65,536"),
        (["active", ds, "-o", str(tmp_path / "run"), "--seed", "99999999999999999999"], "a seed is a 32-bit"),
        (["active", ds, "-o", str(tmp_path / "run"), "--up", "0,0,0"], "--up '0,0,0' is the zero vector"),
        (["make-assets", "-o", str(tmp_path / "a"), "--iters", "999999999999"], "--iters must be at most"),
        (["make-assets", "-o", str(tmp_path / "a"), "--candidates", "100000000"], "--candidates + --test must be"),
    ]
    for argv, expected in cases:
        caplog.clear()
        assert cli.main(argv) == 2, argv
        assert expected in error_text(caplog) and "Config" not in error_text(caplog), (argv, error_text(caplog))
    assert not (tmp_path / "a").exists()  # make-assets checks before it makes its folder


def test_ahmed_resolution_is_bounded_below_and_options_are_named(tmp_path, caplog):
    """ahmed --resolution 1e-9 asked for about 10^20 triangles: the process was killed for memory (rc 137) with no
    message; AhmedBody.slant_deg and a bare 'scale' stood for --slant and --scale."""
    out = str(tmp_path / "a.obj")
    for argv, expected in (
        (["--resolution", "1e-9"], "--resolution 1e-09 m is finer than 0.001 m"),
        (["--slant", "50"], "--slant must be in [0, 40] degrees"),
        (["--scale", "0"], "--scale must be a number from 1e-06 to 1e+06"),
        (["--scale", "1e300"], "--scale must be a number from 1e-06 to 1e+06"),
    ):
        caplog.clear()
        assert cli.main(["ahmed", "-o", out, *argv]) == 2
        assert expected in error_text(caplog) and "AhmedBody" not in error_text(caplog)
    assert not (tmp_path / "a.obj").exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["critical", "assets/ahmed_gaussians.ply", "--top-k", "0"],
        ["bench", "probes", "--every", "0"],
        ["bench", "probes", "--window", "-5"],
        ["bench", "probes", "--cameras", "0"],
    ],
)
def test_counts_that_must_be_positive_are_usage_errors(argv, capsys):
    """`critical --top-k 0` ran and printed nothing; `bench probes --every 0` was a ZeroDivisionError traceback."""
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2 and "must be an integer >= 1" in capsys.readouterr().err


def test_bench_render_sizes_are_bounded(caplog):
    """`bench render --sizes 1000000000@100000x100000` was killed for memory (rc 137) with no message."""
    assert cli.main(["bench", "render", "--sizes", "1000000000@100000x100000"]) == 2
    assert "at most 10,000,000 Gaussians and 8192 pixels a side" in error_text(caplog)
