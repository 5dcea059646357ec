"""Tiny training settings for tests of the reconstruction loops (seconds on two CPU cores)."""

TINY_TRAIN = {"init_points": 150, "sh_degree": 0, "max_gaussians": 300, "init_opacity": 0.5}


def tiny_active_config(**overrides):
    """An ActiveConfig of 4 views on 16 px images with TINY_TRAIN and coarse probes (r = 0.08 m, 20 steps);
    ``overrides`` replace its fields."""
    from nbv.active import ActiveConfig
    from nbv.physics import PhysicsConfig

    base = dict(
        method="random",
        budget=4,
        iterations_per_view=2,
        total_iterations=30,
        resolution=16,
        train=TINY_TRAIN,
        backend="torch",
        physics=PhysicsConfig(particle_radius=0.08, steps=20, dt=0.004),
    )
    return ActiveConfig(**{**base, **overrides})
