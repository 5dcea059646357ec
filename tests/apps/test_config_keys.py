"""Config errors name what the user wrote, never the config classes: the keys of a run's config.json read by `eval`
and its options, and the 'preset' key of an experiment or oracle config with the presets allowed."""

import json

import pytest

from apps import cli

from helpers.logs import error_text


def _run_folder(tmp_path, active: dict):
    run = tmp_path / "run"
    run.mkdir()
    (run / "gaussians.ply").write_text("")  # never read: the config is refused first
    (run / "config.json").write_text(json.dumps({"dataset": "scene", "active": active}))
    return run


@pytest.mark.parametrize(
    "active, expected",
    [
        ({"physics": {"particle_radius": -1}}, "'active.physics.particle_radius' must be"),
        ({"budget": "a"}, "'active.budget' must be"),
        ({"budgett": 3}, "unknown keys in 'active' ['budgett']"),
    ],
)
def test_eval_names_the_keys_of_the_runs_config(tmp_path, caplog, active, expected):
    """They read "PhysicsConfig.particle_radius must be ...", "unknown ActiveConfig keys ..."."""
    run = _run_folder(tmp_path, active)
    assert cli.main(["eval", str(run), "--threads", "1"]) == 2
    msg = error_text(caplog)
    assert expected in msg and str(run / "config.json") in msg and "Config" not in msg, msg
    assert not (run / "eval.json").exists()


@pytest.mark.parametrize("argv", [["--particle-radius", "nan"], ["--probe-steps", "0"]])
def test_eval_options_are_named(tmp_path, capsys, argv):
    """`--particle-radius nan` read "PhysicsConfig.particle_radius must be a finite number > 0"."""
    run = _run_folder(tmp_path, {})
    with pytest.raises(SystemExit) as exc:
        cli.main(["eval", str(run), *argv])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"argument {argv[0]}: must be" in err and "Config" not in err, err


@pytest.mark.parametrize(
    "command, doc",
    [
        (["experiment"], {"scenes": ["scene"], "methods": ["random"], "preset": "nope"}),
        (["study", "oracle"], {"scenes": ["scene"], "seeds": [0], "states": [4], "preset": "nope"}),
    ],
)
def test_an_unknown_preset_names_the_key_and_the_presets(tmp_path, caplog, command, doc):
    """It read "unknown preset 'nope'; use one of [...]", with no key."""
    (tmp_path / "scene").mkdir()
    (tmp_path / "c.json").write_text(json.dumps(doc))
    assert cli.main([*command, str(tmp_path / "c.json")]) == 2
    assert "config: 'preset' must be one of 'paper', 'cpu-small', got 'nope'" in error_text(caplog)
