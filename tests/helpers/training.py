"""Tiny training settings for tests of the reconstruction loops (seconds on two CPU cores)."""

TINY_TRAIN = {"init_points": 150, "sh_degree": 0, "max_gaussians": 300, "init_opacity": 0.5}
