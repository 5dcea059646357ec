"""Config errors speak of the command-line options the user wrote (--scale, --budget), never of the config classes'
fields."""

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


def test_rename_fields_replaces_whole_names_only():
    from apps.options import option_names
    from apps.options.fields import rename_fields
    from nbv.physics import PhysicsConfig

    names = option_names(PhysicsConfig, ("steps", "fill_cavities"), {"fill_cavities": {"flags": ("--no-fill",)}})
    assert names == {"PhysicsConfig.steps": "--steps", "PhysicsConfig.fill_cavities": "--no-fill"}
    assert rename_fields("PhysicsConfig.steps and PhysicsConfig.steps_x", names) == "--steps and PhysicsConfig.steps_x"
