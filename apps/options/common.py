"""Options that many commands take with their own help text: the compute device, a figures JSON, the output,
the scene's up direction, the probe's size, a random seed and the executor of a study. Each is written once here; a
command passes only what its help says differently. The bundled assets' paths are here too, the default inputs of
demo and bench."""

from __future__ import annotations

import argparse
from pathlib import Path

ASSETS = Path(__file__).resolve().parents[2] / "assets"  # the bundled files: the Ahmed body Gaussians and cameras
AHMED_GAUSSIANS = ASSETS / "ahmed_gaussians.ply"
AHMED_CAMERAS = ASSETS / "ahmed_cameras.json"
DEVICES = ("cpu", "cuda")
UP_HELP = (
    "the scene's up direction, rotated to simulation +y: +x, -x, +y, -y, +z, -z or a vector such as 0,-1,0 "
    "(COLMAP captures are often -y; default: +y)"
)


def add_device_option(p, help: str = "compute device; cuda falls back to cpu with a logged warning") -> None:
    """--device: cpu (the default) or cuda."""
    p.add_argument("--device", choices=DEVICES, default="cpu", help=help)


def add_json_option(p, help: str = "also write the figures to this JSON file", type=Path) -> None:
    """--json: the file a benchmark or a check also writes its figures to (default: none)."""
    p.add_argument("--json", type=type, default=None, help=help)


def add_gaussians_option(p, help: str, default: Path | None = AHMED_GAUSSIANS) -> None:
    """--gaussians: the Gaussian set a benchmark runs on (default: the bundled Ahmed body Gaussians)."""
    p.add_argument("--gaussians", type=Path, default=default, help=help)


def add_output_option(p, help: str, default: Path | None = None) -> None:
    """-o / --output: the command's output path; required unless it has a ``default``."""
    p.add_argument("-o", "--output", type=Path, required=default is None, default=default, help=help)


def add_up_option(p, help: str = UP_HELP, default: str | None = "+y", alias: bool = True) -> None:
    """--up (and its older name --up-axis, unless ``alias`` is False): the scene's up direction."""
    flags = ("--up", "--up-axis") if alias else ("--up",)
    extra = {"dest": "up", "metavar": "UP"} if alias else {}
    p.add_argument(*flags, default=default, help=help, **extra)


def add_probe_size_options(p, radius_help: str, steps_help: str, steps_flag: str = "--steps") -> None:
    """--particle-radius (a finite number > 0, m) and the steps per probe (1 to fluidsim.config.MAX_STEPS), both
    None when not given (the preset, or the run's, decides)."""
    from .numbers import positive_number, step_count

    p.add_argument("--particle-radius", type=positive_number, default=None, help=radius_help)
    p.add_argument(steps_flag, type=step_count, default=None, help=steps_help)


def add_seed_option(p, help: str) -> None:
    """--seed: a random seed from 0 to recon.train_config.MAX_SEED (refused when parsed, exit 2), default 0."""
    from .numbers import seed

    p.add_argument("--seed", type=seed, default=0, help=help)


def add_executor_arguments(p: argparse.ArgumentParser, progress_help: str) -> None:
    """--executor, --workers, --threads (per worker), --address (Ray), --output (the results folder) and
    --no-progress: how a study's jobs run (:func:`apps.options.executor.make_executor`)."""
    from ..runtime import thread_count
    from ..taichi_runtime import MAX_THREADS
    from .numbers import int_in

    p.add_argument(
        "--executor",
        choices=("local", "ray"),
        default="local",
        help="local: a process pool here; ray: tasks on a Ray cluster (default: %(default)s)",
    )
    # A process each, started up to the job count (an experiment plans up to 10,000): bounded as --threads is.
    workers = int_in(1, MAX_THREADS)
    p.add_argument("--workers", type=workers, default=1, help="local worker processes (default: %(default)s)")
    p.add_argument(
        "--threads", type=thread_count, default=1, help="torch and Taichi CPU threads per worker (default: %(default)s)"
    )
    p.add_argument(
        "--address",
        default=None,
        help="Ray cluster address for ray.init(address=...), e.g. auto or ray://head:10001 "
        "(default: start a local Ray instance)",
    )
    p.add_argument("--output", type=Path, default=None, help="results folder (default: the config's 'output')")
    p.add_argument("--no-progress", action="store_true", help=progress_help)
