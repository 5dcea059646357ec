"""Test fixtures: one Taichi runtime per test session, debug mode (out-of-bounds access raises), on the arch that
``FLUIDGS_TEST_ARCH`` names.

Environment (docs/testing.md):

- ``FLUIDGS_TEST_ARCH``: ``cpu`` (the default) or ``cuda``. ``cuda`` runs every Taichi kernel of the suite on the
  GPU; on a machine where Taichi finds no usable CUDA device the session stops at once with exit code 4 (a usage
  error) and says so, instead of falling back to the CPU as ``ti.init`` does. Any other value is a usage error.
- ``FLUIDGS_TEST_DEBUG``: ``0`` turns Taichi's debug mode (bounds checks) off, for speed; anything else keeps it.

A test that runs a ``fluidgs`` command in-process re-initialises Taichi with that command's own settings (its
``--device``, ``--threads``, no debug mode). After every test the session's settings are restored when they no
longer hold, so that no test runs on another arch, or without bounds checks, because of the test before it.
"""

from __future__ import annotations

import gc
import os
from dataclasses import dataclass
from pathlib import Path

import pytest
import taichi as ti

ARCH_ENV, DEBUG_ENV = "FLUIDGS_TEST_ARCH", "FLUIDGS_TEST_DEBUG"
ARCHS = {"cpu": ti.cpu, "cuda": ti.cuda}
CPU_THREADS = 2  # the CI machines have two cores
REPO = Path(__file__).resolve().parents[1]  # this file stays at tests/conftest.py when tests move into subfolders


@dataclass(frozen=True)
class TaichiSettings:
    """The Taichi runtime of a test session.

    Attributes:
        arch: "cpu" or "cuda".
        debug: Taichi debug mode (bounds checks in every kernel).
        threads: CPU threads (``cpu_max_num_threads``); also set on CUDA, where only host-side loops use it.
    """

    arch: str = "cpu"
    debug: bool = True
    threads: int = CPU_THREADS

    @classmethod
    def from_environment(cls) -> TaichiSettings:
        """The settings that ``FLUIDGS_TEST_ARCH`` and ``FLUIDGS_TEST_DEBUG`` ask for; pytest.UsageError on a bad
        arch, naming the variable and its choices."""
        arch = os.environ.get(ARCH_ENV, "cpu").strip().lower() or "cpu"
        if arch not in ARCHS:
            raise pytest.UsageError(
                f"{ARCH_ENV}={os.environ[ARCH_ENV]!r}: use one of {', '.join(ARCHS)} "
                f"(the Taichi arch of the test runtime; unset means cpu)"
            )
        return cls(arch=arch, debug=os.environ.get(DEBUG_ENV, "1") != "0")

    def holds(self) -> bool:
        """Whether the current Taichi runtime runs with these settings."""
        runtime = ti.lang.impl.get_runtime()
        if runtime.prog is None:
            return False
        cfg = ti.lang.impl.current_cfg()
        arch_ok = cfg.arch == ti.cuda if self.arch == "cuda" else cfg.arch in (ti.x64, ti.arm64)
        return (
            arch_ok
            and runtime.default_fp == ti.f32
            and bool(cfg.debug) == self.debug
            and cfg.cpu_max_num_threads == self.threads
        )

    def init(self) -> None:
        """``ti.init`` with these settings; stops the session (exit 4) when CUDA is asked for and Taichi fell back
        to the CPU. Garbage is collected first, so that arrays of the old runtime held only by reference cycles
        are freed by that runtime (Taichi frees ndarrays by address through the current runtime)."""
        gc.collect()
        ti.init(
            arch=ARCHS[self.arch],
            cpu_max_num_threads=self.threads,
            debug=self.debug,
            default_fp=ti.f32,
            offline_cache=True,
            log_level=ti.WARN,
        )
        used = ti.lang.impl.current_cfg().arch
        if self.arch == "cuda" and used != ti.cuda:
            pytest.exit(
                f"{ARCH_ENV}=cuda, but Taichi found no usable CUDA device (it started on {used.name}); "
                f"run on a machine with an NVIDIA GPU and driver, or unset {ARCH_ENV} for the CPU",
                returncode=pytest.ExitCode.USAGE_ERROR,
            )


def pytest_configure(config: pytest.Config) -> None:
    TaichiSettings.from_environment()  # a bad FLUIDGS_TEST_ARCH is a usage error before anything is collected


def pytest_report_header(config: pytest.Config) -> str:
    s = TaichiSettings.from_environment()
    return f"taichi: arch={s.arch} ({ARCH_ENV}), debug={s.debug} ({DEBUG_ENV}), cpu threads={s.threads}"


@pytest.fixture(scope="session")
def taichi_settings() -> TaichiSettings:
    """The session's Taichi settings (arch, debug, threads), for tests that compare against them."""
    return TaichiSettings.from_environment()


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime(taichi_settings: TaichiSettings):
    """Initialise Taichi once (only apps and fixtures may call ti.init)."""
    taichi_settings.init()
    yield taichi_settings


@pytest.fixture(autouse=True)
def taichi_settings_restored(taichi_runtime: TaichiSettings):
    """After each test, the session's Taichi settings again, when the test (a CLI command run in-process) changed
    them; free when they still hold."""
    yield
    if not taichi_runtime.holds():
        taichi_runtime.init()


@pytest.fixture(scope="session", autouse=True)
def empty_scene_cache(tmp_path_factory):
    """The empty-scene cache (nbv.physics.empty_cache) of this session in a fresh folder, never the user's."""
    old = os.environ.get("FLUIDGS_CACHE_DIR")
    os.environ["FLUIDGS_CACHE_DIR"] = str(tmp_path_factory.mktemp("empty-scene-cache"))
    yield Path(os.environ["FLUIDGS_CACHE_DIR"])
    if old is None:
        os.environ.pop("FLUIDGS_CACHE_DIR", None)
    else:
        os.environ["FLUIDGS_CACHE_DIR"] = old


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root (where ``assets/`` and ``docs/`` are), independent of where a test file sits."""
    return REPO


@pytest.fixture(scope="session")
def assets_dir(repo_root: Path) -> Path:
    """The bundled ``assets/`` folder."""
    return repo_root / "assets"
