"""Test fixtures: one Taichi runtime per test session, CPU, debug mode (out-of-bounds access raises)."""

import os

import pytest
import taichi as ti


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime():
    """Initialise Taichi once (only apps and fixtures may call ti.init)."""
    debug = os.environ.get("FLUIDGS_TEST_DEBUG", "1") != "0"
    ti.init(arch=ti.cpu, cpu_max_num_threads=2, debug=debug, default_fp=ti.f32, offline_cache=True,
            log_level=ti.WARN)
    yield
