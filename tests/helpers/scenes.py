"""The small scene JSON the app and scene tests share: a 1 m box with walls and one moving fluid block, r = 0.05 m.

Example::

    scene_path.write_text(json.dumps(small_scene(steps=2, solids=[{"points": "pts.npy"}])))
"""

from __future__ import annotations


def small_scene(steps: int = 5, velocity: tuple[float, float, float] = (1, 0, 0), **over) -> dict:
    """A scene dict (as :func:`fluidsim.scene.parse_scene` reads it): ``steps`` steps of 2 ms, the fluid block
    [0.1, 0.5]^3 moving at ``velocity`` (m/s), no solids; ``over`` replaces top-level keys."""
    scene = {
        "particle_radius": 0.05,
        "rest_density": 1000.0,
        "viscosity": 10.0,
        "gravity": [0, -9.81, 0],
        "dt": 0.002,
        "steps": steps,
        "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "walls": True},
        "fluid_blocks": [{"min": [0.1, 0.1, 0.1], "max": [0.5, 0.5, 0.5], "velocity": list(velocity)}],
        "solids": [],
    }
    scene.update(over)
    return scene
