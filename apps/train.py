"""`fluidgs train`: optimise 3D Gaussians on a dataset and write a 3DGS .ply plus a JSON report."""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from fluidsim.files import write_json_atomic

from .options import add_config_options, config_values, dataset_inputs, index_list
from .options.common import add_device_option, add_output_option
from .options.fields import option_names, options_named
from .options.files import check_ply_output
from .runtime import deterministic_torch, thread_count

log = logging.getLogger("fluidgs")


TRAIN_FIELDS = ("background", "init", "init_points", "sh_degree", "max_gaussians", "seed")
TRAIN_OVERRIDES = {
    "background": {
        "choices": ("white", "black", "random"),
        "help": "training background (random: a new colour each iteration, needs alpha in the images)",
    },
    "init": {
        "choices": ("random", "points"),
        "help": "initial Gaussians: uniform random points in a box, or the dataset's point cloud",
    },
    "sh_degree": {
        "choices": (0, 1, 2, 3),
        "help": "largest SH degree (the active degree rises by one every iters / 30 iterations)",
    },
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", type=Path, help="dataset folder (Blender transforms_*.json or COLMAP text model)")
    add_output_option(p, "output 3DGS .ply (written atomically; OUT.json gets the config, timings and metrics)")
    p.add_argument(
        "--iters",
        type=int,
        default=3000,
        help="training iterations (one view each); the 30k reference schedule is compressed to it",
    )
    p.add_argument("--res", type=int, default=64, help="image width in pixels the dataset is resized to (0: native)")
    p.add_argument(
        "--views",
        type=str,
        default=None,
        help="comma-separated train-split indices to train on, e.g. 0,3,7 (default: all train views)",
    )
    from recon.train_config import TrainConfig

    add_config_options(p, TrainConfig, TRAIN_FIELDS, TRAIN_OVERRIDES)
    p.add_argument(
        "--eval-every",
        type=int,
        default=0,
        help="evaluate PSNR/SSIM on the test split every N iterations (0: only at the end), iterations",
    )
    p.add_argument("--threads", type=thread_count, default=None, help="torch CPU threads (default: torch's choice)")
    add_device_option(p, "compute device; cuda falls back to cpu with a logged warning when unavailable (default: cpu)")


def run_command(args: argparse.Namespace) -> int:
    import torch

    from fluidsim.files import check_not_input, check_writable
    from recon.camera import MAX_IMAGE_SIDE
    from recon.device import torch_device
    from recon.formats.ply import save_gaussians
    from recon.train import TrainConfig, evaluate, view_to

    check_ply_output(args.output)
    check_not_input({"-o": args.output, "report": args.output.with_suffix(".json")}, dataset_inputs(args.dataset))
    check_writable(args.output)
    check_writable(args.output.with_suffix(".json"))
    if not 0 <= args.res <= MAX_IMAGE_SIDE:
        raise ValueError(
            f"--res must be a width in pixels from 1 to {MAX_IMAGE_SIDE:,} (or 0 for native), got {args.res}"
        )
    if args.eval_every < 0:
        raise ValueError(f"--eval-every must be >= 0, got {args.eval_every}")
    if args.threads is not None:
        if args.threads < 1:
            raise ValueError(f"--threads must be >= 1, got {args.threads}")
        torch.set_num_threads(args.threads)
    names = {**option_names(TrainConfig, TRAIN_FIELDS, TRAIN_OVERRIDES), "TrainConfig.iterations": "--iters"}
    with options_named(names):
        config = TrainConfig.for_iterations(
            args.iters, **config_values(TrainConfig, args, TRAIN_FIELDS, TRAIN_OVERRIDES)
        )
    seed = config.seed
    device = torch_device(args.device)
    torch.manual_seed(seed)

    dataset, load_s = load_views(args)
    gaussians, train_log = train_with_progress(dataset, config, args.eval_every, device)
    metrics = None
    eval_s = 0.0
    if dataset.test:
        t0 = time.perf_counter()
        metrics = evaluate(gaussians, [view_to(v, device) for v in dataset.test], dataset.background)
        eval_s = time.perf_counter() - t0
        log.info(
            "test split: PSNR %.2f dB, SSIM %.4f over %d views", metrics["psnr"], metrics["ssim"], len(dataset.test)
        )
    else:
        log.warning("%s has no test split; no held-out metrics", args.dataset)
    save_gaussians(gaussians, args.output)
    report = {
        "command": "fluidgs train",
        "dataset": str(args.dataset),
        "output": str(args.output),
        "train_views": [v.name for v in dataset.train],
        "resolution": args.res,
        "device": device,
        "threads": torch.get_num_threads(),
        "config": config.to_dict(),
        "num_gaussians": gaussians.num,
        "timings_s": {"load": load_s, "train": train_log.wall_time_s, "evaluate": eval_s},
        "final_train_loss": train_log.losses[-1] if train_log.losses else None,
        "test": metrics,
        "evaluations": train_log.evaluations,
        "events": train_log.events,
    }
    write_json_atomic(args.output.with_suffix(".json"), report)
    log.info(
        "wrote %s (%d Gaussians) and %s; training took %.1f s",
        args.output,
        gaussians.num,
        args.output.with_suffix(".json"),
        train_log.wall_time_s,
    )
    return 0


def load_views(args: argparse.Namespace) -> tuple:
    """(dataset with the --views of its train split, seconds the loading took)."""
    from recon.datasets import load_dataset

    start = time.perf_counter()
    dataset = load_dataset(args.dataset, resolution=args.res or None)
    n = len(dataset.train)
    chosen = (
        None
        if args.views is None
        else index_list(args.views, "--views", n, what="view", range_hint=f"the train split has {n} views (0..{n - 1})")
    )
    if chosen is not None:
        dataset.train = [dataset.train[i] for i in chosen]
    load_s = time.perf_counter() - start
    log.info(
        "%s: %d train views (%d x %d px), %d test views",
        args.dataset,
        len(dataset.train),
        dataset.train[0].camera.width,
        dataset.train[0].camera.height,
        len(dataset.test),
    )
    if args.eval_every and not dataset.test:
        raise ValueError(f"--eval-every {args.eval_every} needs test views, but {args.dataset} has no test split")
    return dataset, load_s


def train_with_progress(dataset, config, eval_every: int, device: str) -> tuple:
    """(Gaussians, TrainLog) of :func:`recon.train.train`, deterministic, with a progress bar."""
    from tqdm import tqdm

    from recon.train import train

    with tqdm(total=config.iterations, desc="train", unit="it") as bar:

        def on_step(st) -> None:
            bar.update(1)
            if st.iteration % 10 == 0 or st.iteration == config.iterations:
                bar.set_postfix(loss=f"{st.loss:.4f}", psnr=f"{st.psnr:.2f}", gaussians=st.num_gaussians, refresh=False)

        with deterministic_torch():
            gaussians, train_log = train(
                dataset,
                config,
                callback=on_step,
                eval_views=dataset.test,
                evaluate_every=eval_every,
                device=device,
            )
    return gaussians, train_log
