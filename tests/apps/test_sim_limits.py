"""`fluidgs sim`: the scene's counts and limits are refused before anything is allocated, each in one line that names
the key or option and the fix (no traceback): neighbour lists, wall layers, the viscous time step, steps."""

import json
import math

import pytest

from apps import cli

from helpers.logs import error_text
from helpers.scenes import small_scene


def _scene(**over) -> dict:
    return small_scene(**{"steps": 2, **over})


def test_max_neighbors_1e9_is_refused_before_allocating_naming_the_key(tmp_path, caplog, capsys):
    """`"max_neighbors": 1e9` gave a Taichi allocation traceback (an overflowed size of 1.8e19 bytes)."""
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(_scene(solver={"max_neighbors": 1_000_000_000})))
    assert cli.main(["sim", str(scene), "-o", str(tmp_path / "o.h5"), "--threads", "1"]) == 2
    msg = error_text(caplog)
    assert "'solver.max_neighbors' = 1000000000" in msg and "remove 'max_neighbors'" in msg
    assert "Traceback" not in capsys.readouterr().err and not (tmp_path / "o.h5").exists()


def test_max_neighbors_enters_the_memory_estimate():
    from fluidsim.memory import BYTES_PER_LIST_SLOT, default_list_capacity, estimate_scene_memory
    from fluidsim.scene import parse_scene

    plain = estimate_scene_memory(parse_scene(_scene(), "."))
    wide = estimate_scene_memory(parse_scene(_scene(solver={"max_neighbors": 1000}), "."))
    extra = 1000 - default_list_capacity(parse_scene(_scene(), ".").config)
    assert plain.list_bytes == 0
    assert wide.bytes - plain.bytes == pytest.approx(plain.fluid_particles * extra * BYTES_PER_LIST_SLOT["f32"])


def test_a_million_wall_layers_blame_the_wall_layers_not_the_domain(tmp_path, caplog):
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(_scene(domain={"min": [0, 0, 0], "max": [1, 1, 1], "wall_layers": 1_000_000})))
    assert cli.main(["sim", str(scene), "-o", str(tmp_path / "o.h5"), "--threads", "1"]) == 2
    msg = error_text(caplog)
    assert "'domain.wall_layers' = 1000000" in msg and "set 'domain.wall_layers' to 2" in msg
    assert "shrink 'domain'" not in msg


def test_the_viscous_limit_follows_the_diffusion_bound():
    """dt <= 0.125 (h/2)^2 rho0 / mu: at r = 0.05 m (h = 0.2 m), rho0 = 1000, dt = 0.002 s the bound is 625 Pa s
    (measured with `fluidgs sim`: 600 Pa s ran 60 steps, 1000 Pa s diverged at step 19)."""
    from fluidsim.config import SolverConfig
    from fluidsim.simulation import check_viscous_time_step, viscous_dt_limit

    cfg = SolverConfig(particle_radius=0.05, dt=0.002, viscosity=600.0)
    assert viscous_dt_limit(cfg, 625.0) == pytest.approx(0.002)
    assert viscous_dt_limit(cfg, 0.0) == math.inf
    check_viscous_time_step(cfg)
    with pytest.raises(ValueError, match="viscosity 1000 Pa s.*lower viscosity to 625 Pa s"):
        check_viscous_time_step(SolverConfig(particle_radius=0.05, dt=0.002, viscosity=1000.0), "scene s.json")
    with pytest.raises(ValueError, match="boundary_viscosity 5000 Pa s"):
        check_viscous_time_step(SolverConfig(particle_radius=0.05, dt=0.002, boundary_viscosity=5000.0))


def test_sim_steps_0_names_the_option(tmp_path, caplog):
    (tmp_path / "scene.json").write_text(
        json.dumps(
            {
                "particle_radius": 0.05,
                "dt": 0.002,
                "steps": 2,
                "rest_density": 1000.0,
                "viscosity": 10.0,
                "domain": {"min": [0, 0, 0], "max": [1, 1, 1]},
                "fluid_blocks": [{"min": [0.1] * 3, "max": [0.5] * 3}],
            }
        )
    )
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "o.h5"), "--steps", "0"]) == 2
    assert "--steps must be an integer >= 1" in error_text(caplog) and "scene key" not in error_text(caplog)
