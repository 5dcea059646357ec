"""`fluidgs train`: optimise 3D Gaussians on a dataset and write a 3DGS .ply plus a JSON report."""

from __future__ import annotations

import argparse
import json
import logging
import os
import time
from contextlib import contextmanager
from pathlib import Path

from .runtime import positive_int

log = logging.getLogger("fluidgs")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", type=Path, help="dataset folder (Blender transforms_*.json or COLMAP text model)")
    p.add_argument("-o", "--output", type=Path, required=True,
                   help="output 3DGS .ply (written atomically; OUT.json gets the config, timings and metrics)")
    p.add_argument("--iters", type=int, default=3000,
                   help="training iterations (one view each); the 30k reference schedule is compressed to it")
    p.add_argument("--res", type=int, default=64, help="image width in pixels the dataset is resized to (0: native)")
    p.add_argument("--views", type=str, default=None,
                   help="comma-separated train-split indices to train on, e.g. 0,3,7 (None: all train views)")
    p.add_argument("--background", choices=("white", "black", "random"), default="white",
                   help="training background (random: a new colour each iteration, needs alpha in the images)")
    p.add_argument("--init", choices=("random", "points"), default="random",
                   help="initial Gaussians: uniform random points in a box, or the dataset's point cloud")
    p.add_argument("--init-points", type=int, default=5000, help="number of random initial points (Gaussians)")
    p.add_argument("--sh-degree", type=int, default=3, choices=(0, 1, 2, 3),
                   help="largest SH degree (the active degree rises by one every iters / 30 iterations)")
    p.add_argument("--max-gaussians", type=int, default=None,
                   help="cap on the number of Gaussians during densification, count (None: no cap)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw")
    p.add_argument("--eval-every", type=int, default=0,
                   help="evaluate PSNR/SSIM on the test split every N iterations (0: only at the end), iterations")
    p.add_argument("--threads", type=positive_int, default=None, help="torch CPU threads (None: torch's choice)")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="compute device; cuda falls back to cpu with a logged warning when unavailable")


def parse_views(text: str | None, count: int) -> list[int] | None:
    """Indices of ``--views`` ("0,3,7"), checked against ``count`` train views; None for all."""
    if text is None:
        return None
    try:
        idx = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise ValueError(f"--views must be comma-separated integers such as 0,3,7, got {text!r}") from None
    if not idx:
        raise ValueError("--views is empty; give at least one train-split index, e.g. 0,1,2")
    bad = [i for i in idx if not 0 <= i < count]
    if bad:
        raise ValueError(f"--views {bad} out of range: the train split has {count} views (indices 0..{count - 1})")
    if len(set(idx)) != len(idx):
        raise ValueError(f"--views {text!r} repeats an index; list each train view once")
    return idx


def check_output(path: Path) -> None:
    """Raise before any training when ``path`` is not a writable .ply destination."""
    if path.suffix.lower() != ".ply":
        raise ValueError(f"{path}: the output must be a .ply file (e.g. -o out/scene.ply)")
    parent = path.absolute().parent
    if not parent.is_dir():
        raise ValueError(f"{parent}: the output folder does not exist; create it first")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{parent}: the output folder is not writable; choose another -o")
    if path.is_dir():
        raise ValueError(f"{path}: is a folder; give a .ply file name")


def write_json_atomic(path: Path, data: dict) -> None:
    """Write ``data`` as indented JSON via a temporary file in the same folder and os.replace."""
    from fluidsim.output import atomic_output

    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2) + "\n")


# The files of a dataset folder that loading reads (cameras, points, normalisation), at the top, in sparse/ and in
# sparse/0/: no output may overwrite them. Images are left out: no command that reads a dataset writes images.
DATASET_FILES = ("transforms_*.json", "dataset.json", "mesh.ply", "cameras.txt", "cameras.bin", "images.txt",
                 "images.bin", "points3D.txt", "points3D.bin", "points3D.ply")


def dataset_inputs(dataset: Path) -> list[tuple[str, Path]]:
    """("DATASET file", path) for each existing :data:`DATASET_FILES` file of a dataset folder (or the
    transforms_*.json given), for :func:`fluidsim.output.check_not_input`."""
    root = Path(dataset)
    if root.is_file():
        return [("DATASET file", root)]
    return [("DATASET file", f) for folder in (root, root / "sparse", root / "sparse" / "0") if folder.is_dir()
            for pattern in DATASET_FILES for f in sorted(folder.glob(pattern))]


@contextmanager
def deterministic_torch():
    """Run the block with ``torch.use_deterministic_algorithms(True, warn_only=True)``, then restore the setting."""
    import torch

    before = torch.are_deterministic_algorithms_enabled()
    warn_before = torch.is_deterministic_algorithms_warn_only_enabled()
    torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(before, warn_only=warn_before)


def select_device(requested: str) -> str:
    import torch

    if requested == "cuda" and not torch.cuda.is_available():
        log.warning("--device cuda requested but no CUDA device is usable; falling back to the CPU")
        return "cpu"
    return requested


def run_command(args: argparse.Namespace) -> int:
    import torch
    from tqdm import tqdm

    from fluidsim.output import check_not_input, check_writable
    from recon.datasets import load_dataset
    from recon.ply import save_gaussians
    from recon.train import TrainConfig, evaluate, train, view_to

    check_output(args.output)
    check_not_input({"-o": args.output, "report": args.output.with_suffix(".json")}, dataset_inputs(args.dataset))
    check_writable(args.output)
    check_writable(args.output.with_suffix(".json"))
    if args.res < 0:
        raise ValueError(f"--res must be a width in pixels >= 1 (or 0 for native), got {args.res}")
    if args.eval_every < 0:
        raise ValueError(f"--eval-every must be >= 0, got {args.eval_every}")
    if args.threads is not None:
        if args.threads < 1:
            raise ValueError(f"--threads must be >= 1, got {args.threads}")
        torch.set_num_threads(args.threads)
    config = TrainConfig.for_iterations(args.iters, background=args.background, init=args.init,
                                        init_points=args.init_points, sh_degree=args.sh_degree, seed=args.seed,
                                        max_gaussians=args.max_gaussians)
    device = select_device(args.device)
    torch.manual_seed(args.seed)

    start = time.perf_counter()
    dataset = load_dataset(args.dataset, resolution=args.res or None)
    chosen = parse_views(args.views, len(dataset.train))
    if chosen is not None:
        dataset.train = [dataset.train[i] for i in chosen]
    load_s = time.perf_counter() - start
    log.info("%s: %d train views (%d x %d px), %d test views", args.dataset, len(dataset.train),
             dataset.train[0].camera.width, dataset.train[0].camera.height, len(dataset.test))
    if args.eval_every and not dataset.test:
        raise ValueError(f"--eval-every {args.eval_every} needs test views, but {args.dataset} has no test split")

    with tqdm(total=config.iterations, desc="train", unit="it") as bar:
        def on_step(st) -> None:
            bar.update(1)
            if st.iteration % 10 == 0 or st.iteration == config.iterations:
                bar.set_postfix(loss=f"{st.loss:.4f}", psnr=f"{st.psnr:.2f}", gaussians=st.num_gaussians,
                                refresh=False)

        with deterministic_torch():
            gaussians, train_log = train(dataset, config, callback=on_step, eval_views=dataset.test,
                                         evaluate_every=args.eval_every, device=device)
    metrics = None
    eval_s = 0.0
    if dataset.test:
        t0 = time.perf_counter()
        metrics = evaluate(gaussians, [view_to(v, device) for v in dataset.test], dataset.background)
        eval_s = time.perf_counter() - t0
        log.info("test split: PSNR %.2f dB, SSIM %.4f over %d views", metrics["psnr"], metrics["ssim"],
                 len(dataset.test))
    else:
        log.warning("%s has no test split; no held-out metrics", args.dataset)
    save_gaussians(gaussians, args.output)
    report = {
        "command": "fluidgs train", "dataset": str(args.dataset), "output": str(args.output),
        "train_views": [v.name for v in dataset.train], "resolution": args.res, "device": device,
        "threads": torch.get_num_threads(), "config": config.to_dict(),
        "num_gaussians": gaussians.num,
        "timings_s": {"load": load_s, "train": train_log.wall_time_s, "evaluate": eval_s},
        "final_train_loss": train_log.losses[-1] if train_log.losses else None,
        "test": metrics, "evaluations": train_log.evaluations, "events": train_log.events,
    }
    write_json_atomic(args.output.with_suffix(".json"), report)
    log.info("wrote %s (%d Gaussians) and %s; training took %.1f s", args.output, gaussians.num,
             args.output.with_suffix(".json"), train_log.wall_time_s)
    return 0

