"""`fluidgs make-assets`: regenerate the bundled trained Ahmed-body Gaussians and their candidate cameras.

Pipeline (deterministic for a given seed and thread count):

1. the procedural Ahmed body (:func:`recon.ahmed.write_ahmed`, 25 deg slant, with stilts, metres, Y up);
2. ``render-dataset`` of it (:func:`recon.mesh_render.render_mesh_dataset`): normalised to a box of 4
   scene units, cameras at radius 6 on the full sphere, ``--candidates`` train / candidate views and
   ``--test`` held-out views at ``--res`` px;
3. 3DGS training (:func:`recon.train.train`) on the first ``--train-views`` candidates with the reference
   schedule compressed to ``--iters`` iterations, SH degree 0 and at most ``--max-gaussians`` Gaussians so
   the .ply stays small;
4. writes ``ahmed_gaussians.ply`` (3DGS layout), ``ahmed_cameras.json`` (all candidate cameras, Blender
   ``transforms`` layout with explicit intrinsics ``w``, ``h``, ``fl_x``, ``fl_y``, ``cx``, ``cy``) and
   ``ahmed_asset.json`` (command, seed, settings, mesh normalisation, test PSNR/SSIM, timings).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import tempfile
import time
from pathlib import Path

from fluidsim.files import write_json_atomic

from .options.common import add_output_option, add_seed_option
from .runtime import deterministic_torch, thread_count

log = logging.getLogger("fluidgs")

GAUSSIANS_FILE = "ahmed_gaussians.ply"
CAMERAS_FILE = "ahmed_cameras.json"
REPORT_FILE = "ahmed_asset.json"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_output_option(p, "folder of the asset files", default=Path("assets"))
    add_seed_option(p, "seed of the cameras and of training")
    p.add_argument("--res", type=int, default=64, help="image width = height, pixels")
    p.add_argument("--candidates", type=int, default=40, help="candidate (train-split) views written to the cameras")
    p.add_argument("--test", type=int, default=10, help="held-out views for the reported PSNR/SSIM")
    p.add_argument("--train-views", type=int, default=10, help="the first N candidates are the training views")
    p.add_argument("--iters", type=int, default=3000, help="training iterations")
    p.add_argument(
        "--max-gaussians",
        type=int,
        default=20000,
        help="cap on the Gaussian count (20000 x 68 bytes keeps the .ply under 1.4 MB)",
    )
    p.add_argument("--sh-degree", type=int, default=0, choices=(0, 1), help="SH degree of the asset (size!)")
    p.add_argument(
        "--threads",
        type=thread_count,
        default=1,
        help="torch CPU threads (the result is bit-reproducible for a fixed thread count)",
    )


def cameras_json(cameras, fov_x: float) -> dict:
    """Blender ``transforms`` dict of ``cameras`` with explicit intrinsics (all cameras share one size)."""
    c0 = cameras[0]
    return {
        "camera_angle_x": fov_x,
        "w": c0.width,
        "h": c0.height,
        "fl_x": c0.fx,
        "fl_y": c0.fy,
        "cx": c0.cx,
        "cy": c0.cy,
        "frames": [
            {"file_path": f"./train/{c.name}", "name": c.name, "transform_matrix": c.opengl_c2w().tolist()}
            for c in cameras
        ],
    }


def read_cameras_json(path: Path) -> list:
    """The cameras of a :func:`cameras_json` file (for tests and tools): :func:`recon.datasets.load_cameras`."""
    from recon.datasets import load_cameras

    return load_cameras(path)


def run_command(args: argparse.Namespace) -> int:
    import torch

    from recon.ahmed import write_ahmed
    from recon.datasets import load_dataset
    from recon.formats.ply import save_gaussians
    from recon.mesh_render import render_mesh_dataset
    from recon.train import evaluate

    from .options import check_output_folder

    out = args.output
    check_arguments(args)
    mesh_cfg, config = asset_configs(args)  # checked before the output folder is made or the seed is set
    check_output_folder(out, "-o")
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="fluidgs-assets-") as tmp:
        mesh_path = Path(tmp) / "ahmed.obj"
        write_ahmed(mesh_path)
        data_dir = render_mesh_dataset(mesh_path, Path(tmp) / "dataset", mesh_cfg, progress=False)
        normalisation = json.loads((data_dir / "dataset.json").read_text())
        dataset = load_dataset(data_dir)
        candidates = [v.camera for v in dataset.train]
        dataset.train = dataset.train[: args.train_views]
        render_s = time.perf_counter() - start
        shown = (len(candidates), len(dataset.test), args.res, render_s)
        log.info("rendered %d candidate and %d test views at %d px in %.1f s", *shown)

        gaussians, train_log = train_assets(dataset, config)
        metrics = evaluate(gaussians, dataset.test, dataset.background)
    ply_path = save_gaussians(gaussians, out / GAUSSIANS_FILE)
    write_json_atomic(out / CAMERAS_FILE, cameras_json(candidates, math.radians(mesh_cfg.fov_x)))
    report = {
        "command": f"fluidgs make-assets -o {out} --seed {args.seed} --res {args.res} --candidates {args.candidates} "
        f"--test {args.test} --train-views {args.train_views} --iters {args.iters} "
        f"--max-gaussians {args.max_gaussians} --sh-degree {args.sh_degree} --threads {args.threads}",
        "seed": args.seed,
        "mesh": "recon.ahmed.write_ahmed(): Ahmed body, 25 deg slant, stilts, metres, Y up",
        "normalisation": {k: normalisation[k] for k in ("normalization", "scale", "offset", "up_axis")},
        "dataset": {k: v for k, v in normalisation["config"].items()},
        "candidate_cameras": CAMERAS_FILE,
        "train_view_indices": list(range(args.train_views)),
        "num_gaussians": gaussians.num,
        "sh_degree": gaussians.sh_degree,
        "train_config": config.to_dict(),
        "test_psnr_db": metrics["psnr"],
        "test_ssim": metrics["ssim"],
        "test_views": len(metrics["per_view"]),
        "timings_s": {"render_dataset": render_s, "train": train_log.wall_time_s, "total": time.perf_counter() - start},
        "threads": args.threads,
        "torch": torch.__version__,
    }
    write_json_atomic(out / REPORT_FILE, report)
    sizes = {p.name: p.stat().st_size for p in (ply_path, out / CAMERAS_FILE, out / REPORT_FILE)}
    log.info(
        "wrote %s: %d Gaussians, test PSNR %.2f dB, SSIM %.4f; sizes %s bytes; %.0f s in all",
        out,
        gaussians.num,
        metrics["psnr"],
        metrics["ssim"],
        sizes,
        report["timings_s"]["total"],
    )
    return 0


def asset_configs(args: argparse.Namespace):
    """(MeshDatasetConfig, TrainConfig) of the command line; their errors name the options."""
    from recon.mesh_render import MeshDatasetConfig
    from recon.train import TrainConfig

    from .options.fields import options_named

    train = {"iterations": "--iters", "seed": "--seed", "max_gaussians": "--max-gaussians"}
    mesh = {"n_train": "--candidates", "n_test": "--test", "resolution": "--res", "seed": "--seed"}
    names = {f"TrainConfig.{k}": v for k, v in train.items()} | {f"MeshDatasetConfig.{k}": v for k, v in mesh.items()}
    with options_named(names | {"MeshDatasetConfig.supersample": "supersampling"}):
        mesh_cfg = MeshDatasetConfig(n_train=args.candidates, n_test=args.test, resolution=args.res, seed=args.seed)
        config = TrainConfig.for_iterations(
            args.iters, sh_degree=args.sh_degree, seed=args.seed, max_gaussians=args.max_gaussians
        )
    return mesh_cfg, config


def check_arguments(args: argparse.Namespace) -> None:
    """The counts and sizes of the command line, refused before anything is rendered."""
    for name in ("res", "candidates", "iters", "max_gaussians", "threads", "train_views"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.train_views > args.candidates:
        raise ValueError(f"--train-views {args.train_views} exceeds --candidates {args.candidates}")
    if args.test < 1:
        raise ValueError(f"--test must be >= 1 to report a held-out PSNR, got {args.test}")


def train_assets(dataset, config) -> tuple:
    """(Gaussians, TrainLog) of :func:`recon.train.train` on the rendered views, deterministic, with a progress bar."""
    from tqdm import tqdm

    from recon.train import train

    with tqdm(total=config.iterations, desc="make-assets train", unit="it") as bar:

        def on_step(st) -> None:
            bar.update(1)
            if st.iteration % 10 == 0:
                bar.set_postfix(loss=f"{st.loss:.4f}", psnr=f"{st.psnr:.2f}", gaussians=st.num_gaussians, refresh=False)

        with deterministic_torch():
            gaussians, train_log = train(dataset, config, callback=on_step)
    return gaussians, train_log
