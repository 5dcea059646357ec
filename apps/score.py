"""`fluidgs score GAUSSIANS.ply --cameras transforms.json -o scores.json`: rank candidate views by S(T) (Eq. 4-5).

S(T) = sum over the Gaussians visible in view T of w_g D_g, with w_g = clamp(pi R_g^2 / (H W), 0, 1) from the
renderer's screen-space radii R_g. D_g comes from RESULT.h5 (``--result``) or from a fresh probe run.
Prints a ranked table and writes scores.json (per candidate: index, name, score, rank, visible count; and
the settings) and, per view, a PNG with the render beside a D_g heat-map of the same view (the Gaussians
re-coloured by D_g on the TURBO map, rendered with the same camera), rank and score written on it.

Cameras: a Blender / NeRF-synthetic ``transforms.json`` (``camera_angle_x`` or ``fl_x``, frames with
``transform_matrix``); the image size from ``w``/``h`` keys, else the frame's image file, else ``--res``.
The cameras' frame must be the Gaussians' frame (scene units).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from .simulate import (
    add_physics_arguments,
    add_record_arguments,
    check_output_file,
    load_gaussians_checked,
    physics_config_from_args,
    record_config_from_args,
    save_diverged,
    write_json,
)

log = logging.getLogger("fluidgs")
METRICS = ("max", "mean", "-x", "+x", "-z", "+z", "-y")
PNG_TOP = 5  # views rendered to PNG by default (the scores themselves need no render)


def add_camera_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cameras", type=Path, required=True,
                   help="Blender/NeRF transforms.json with the candidate cameras, in the Gaussians' frame")
    p.add_argument("--res", type=int, default=None,
                   help="image width in pixels when the cameras file gives no w/h and no images (height from the "
                        "aspect of w/h when known, else square)")
    p.add_argument("--render-width", type=int, default=320,
                   help="render (and weight) at most this width in pixels; the weights pi R^2/(HW) barely change "
                        "with resolution")
    p.add_argument("--candidates", default=None, help="comma list of camera indices to score (default: all)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("gaussians", type=Path, help="Gaussians (.ply, .compressed.ply, .spz, .splat, .npz), scene units")
    add_camera_arguments(p)
    p.add_argument("-o", "--output", type=Path, required=True, help="scores JSON file (written atomically)")
    p.add_argument("--result", type=Path, default=None,
                   help="RESULT.h5 of `fluidgs simulate` for these Gaussians (default: simulate now)")
    p.add_argument("--save-result", type=Path, default=None, help="when simulating, also write RESULT.h5 here")
    p.add_argument("--top-k", type=int, default=None, help="print only the best K views (default: all)")
    p.add_argument("--metric", choices=METRICS, default="max",
                   help="per-Gaussian metric: D_g max over probes, mean over probes, or one probe's D_g (1/s)")
    p.add_argument("--unweighted", action="store_true", help="sum D_g over visible Gaussians without Eq. 5 weights")
    p.add_argument("--occlusion", action="store_true",
                   help="count only Gaussians not hidden behind the others (a coarse depth buffer of the projected "
                        "centres, composited front to back in cells of about one footprint radius; not in the "
                        "paper, whose visibility is frustum culling)")
    p.add_argument("--png-dir", type=Path, default=None,
                   help="folder for the per-view PNGs (default: next to the output, <stem>_views)")
    p.add_argument("--no-png", action="store_true", help="skip the per-view PNGs")
    p.add_argument("--png-top", type=int, default=PNG_TOP,
                   help="render PNGs of the best N views only (scores need no render; default: %(default)s)")
    p.add_argument("--png-all", action="store_true", help="render a PNG of every candidate view")
    add_record_arguments(p)
    add_physics_arguments(p, cameras=True)


def load_cameras(path: Path, res: int | None = None) -> list:
    """Cameras of a Blender/NeRF ``transforms.json`` scaled to width ``res``: :func:`recon.datasets.load_cameras`.

    Raises:
        ValueError: naming the file, the frame and the key when something is missing or malformed.
    """
    from recon.datasets import load_cameras as read_cameras

    return read_cameras(path, res)


def parse_candidates(text: str | None, count: int) -> list[int]:
    """'0,3,5' -> indices (all when None); ValueError naming --candidates on an empty list, a non-integer, an
    out-of-range or a repeated entry."""
    if text is None:
        return list(range(count))
    try:
        idx = [int(s) for s in text.split(",") if s.strip()]
    except ValueError as exc:
        raise ValueError(f"--candidates must be a comma list of camera indices such as 0,3,5, got {text!r}") from exc
    if not idx:
        raise ValueError(f"--candidates {text!r} lists no camera; give indices such as 0,3,5 (0..{count - 1}), or "
                         f"leave the option out to score all {count} cameras")
    bad = [i for i in idx if not 0 <= i < count]
    if bad:
        raise ValueError(f"--candidates {bad} out of range: the cameras file has {count} cameras (0..{count - 1})")
    repeated = sorted({i for i in idx if idx.count(i) > 1})
    if repeated:
        raise ValueError(f"--candidates {text!r} lists camera(s) {repeated} more than once; list each camera once")
    return idx


def render_size(cam, max_width: int):
    """The camera scaled down so its width is at most ``max_width`` pixels."""
    if max_width < 8:
        raise ValueError(f"--render-width must be >= 8 pixels, got {max_width}")
    return cam.scaled(max_width / cam.width) if cam.width > max_width else cam


def check_cameras_see(gaussians, cameras, names: list[str]) -> np.ndarray:
    """Projected centre counts per camera; ValueError when no camera sees any Gaussian (before simulating)."""
    from nbv.scores import projected_counts

    counts = projected_counts(gaussians.means, cameras).numpy()
    if counts.max(initial=0) == 0:
        raise ValueError(f"none of the {len(cameras)} candidate cameras sees any Gaussian (all centres are behind "
                         "them or outside the image); check that the cameras and the Gaussians share one frame "
                         "and scale")
    for n, c in zip(names, counts, strict=True):
        if c == 0:
            log.warning("camera %s sees no Gaussian; its score is 0", n)
    return counts


def metric_values(result, metric: str) -> np.ndarray:
    """The per-Gaussian metric chosen by --metric from a PhysicsResult."""
    if metric == "max":
        return result.divergence
    if metric == "mean":
        return result.divergence_mean
    if metric not in result.directions:
        raise ValueError(f"--metric {metric}: the result has no probe {metric} (it has {','.join(result.directions)})")
    return result.per_probe[result.directions.index(metric)]


def obtain_result(args, gaussians, config, record=None):
    """PhysicsResult from --result, or a fresh simulation (then saved to --save-result when given; ``record``: the
    probes to record, :class:`nbv.trajectory.RecordConfig`)."""
    from nbv.physics import check_result_matches, load_result, save_result, simulate_gaussians

    from .runtime import init_taichi

    if args.result is not None:
        result = load_result(args.result)
        check_result_matches(result, gaussians, args.result)
        for d, notes in result.warnings.items():  # a fresh simulation logs them as its probes end
            for note in notes:
                log.warning("%s, probe %s: %s", args.result, d, note)
        return result
    init_taichi(args.device, config.precision, args.threads)
    result = simulate_gaussians(gaussians, config, progress=True, source=str(args.gaussians), record=record)
    if args.save_result is not None:
        save_result(args.save_result, result)
    return result


def label(img: np.ndarray, lines: list[str]) -> np.ndarray:
    """Write text lines (black on a white box) in the top-left corner of a BGR uint8 image."""
    import cv2

    scale = max(0.35, img.shape[1] / 900)
    for k, text in enumerate(lines):
        y = int(16 * scale / 0.45) * (k + 1)
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
        cv2.rectangle(img, (2, y - th - 3), (6 + tw, y + 3), (255, 255, 255), -1)
        cv2.putText(img, text, (4, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def to_bgr(image, min_width: int = 320) -> np.ndarray:
    """[H, W, 3] float RGB tensor in [0, 1] -> BGR uint8, enlarged (nearest) to at least ``min_width`` pixels."""
    import cv2

    arr = image.detach().cpu().clamp(0, 1).numpy()
    out = np.ascontiguousarray((arr[..., ::-1] * 255 + 0.5).astype(np.uint8))
    if out.shape[1] < min_width:
        f = -(-min_width // out.shape[1])
        out = cv2.resize(out, (out.shape[1] * f, out.shape[0] * f), interpolation=cv2.INTER_NEAREST)
    return out


def render_candidates(gaussians, cameras, heat_gaussians=None, device: str = "cpu", progress: bool = True):
    """Render every camera; yields (RenderOutput with radii/visible on the CPU, heat-map image or None)."""
    import torch
    from tqdm import tqdm

    from recon.render import render

    dev = torch.device(device)
    g = gaussians.detach().to(dev)
    heat = heat_gaussians.detach().to(dev) if heat_gaussians is not None else None
    with torch.no_grad():
        for cam in tqdm(cameras, desc="render", unit="view", disable=not progress):
            out = render(g, cam, background=1.0)
            himg = render(heat, cam, background=0.0).image if heat is not None else None
            yield out, himg


def torch_device(name: str) -> str:
    """'cuda' when asked for and available, else 'cpu' (with a logged warning)."""
    import torch

    if name == "cuda" and not torch.cuda.is_available():
        log.warning("--device cuda requested but torch sees no CUDA device; rendering on the CPU")
        return "cpu"
    return name


def print_table(rows: list[dict], top_k: int | None, value: str = "score") -> None:
    shown = rows if top_k is None else rows[:top_k]
    print(f"{'rank':>4}  {'index':>5}  {'name':<24} {value:>14}  {'visible':>8}")
    for r in shown:
        print(f"{r['rank']:>4}  {r['index']:>5}  {r['name'][:24]:<24} {r[value]:>14.6g}  {r['visible']:>8}")


def score_views(gaussians, cams, idx: list[int], result, metric: str = "max", png_dir: Path | None = None, *,
                weighted: bool = True, occlusion: bool = False, device: str = "cpu",
                visible_centres=None, progress: bool = True, png_top: int | None = PNG_TOP) -> list[dict]:
    """Score the candidates from the projection alone, rank them and render PNGs of the best ones.

    S(T) needs the screen radii and visibility only (:func:`nbv.scores.projected_view_scores`, equal to the
    renderer's), so no candidate is rendered to score it; full images are made for the PNGs only.

    Args:
        gaussians: the GaussianSet (scene units). cams: the candidate cameras; idx: their indices in the file.
        result: a PhysicsResult of these Gaussians. metric: see --metric.
        png_dir: folder for ``rank<r>_<index>_<name>.png`` (render | D_g heat-map), or None.
        weighted: Eq. 5 weights. occlusion: the coarse depth test (:class:`nbv.scores.DepthBuffer`).
        device: torch device. visible_centres: [C] projected-centre counts for the rows.
        png_top: PNGs for the best ``png_top`` views only (None: every view).
    Returns:
        rows (best first): rank, index, name, score, visible (the Gaussians counted; and visible_centres when
        given).
    """
    import time

    import torch

    from nbv.scores import DepthBuffer, projected_view_scores, rank

    values = metric_values(result, metric)
    dev = torch.device(torch_device(device))
    start = time.perf_counter()
    scored = projected_view_scores(torch.from_numpy(np.asarray(values)), gaussians.detach().to(dev), cams,
                                   weighted=weighted, depth_buffer=DepthBuffer() if occlusion else None)
    log.info("scored %d views of %d Gaussians from the projection in %.2f s", len(cams), gaussians.num,
             time.perf_counter() - start)
    s = scored.scores
    order = rank(s).tolist()
    ranks = {i: r + 1 for r, i in enumerate(order)}
    rows = []
    for k in order:
        row = {"rank": ranks[k], "index": idx[k], "name": cams[k].name, "score": float(s[k]),
               "visible": int(scored.counted[k])}
        if visible_centres is not None:
            row["visible_centres"] = int(visible_centres[k])
        rows.append(row)
    if png_dir is not None:
        shown = order if png_top is None else order[:png_top]
        write_view_pngs(gaussians, cams, shown, rows, values, metric, png_dir, str(dev), progress)
    return rows


def write_view_pngs(gaussians, cams, shown: list[int], rows: list[dict], values, metric: str, png_dir: Path,
                    device: str, progress: bool) -> None:
    """Render the views ``shown`` (positions in ``cams``, best first) and write render | D_g heat-map PNGs."""
    import cv2

    from fluidsim.output import atomic_output
    from nbv.heatmap import color_scale, colored_gaussians

    vmax = color_scale(values)
    heat = colored_gaussians(gaussians, values, vmax=vmax)
    png_dir.mkdir(parents=True, exist_ok=True)
    renders = render_candidates(gaussians, [cams[k] for k in shown], heat, device, progress)
    for r, (k, (out, himg)) in enumerate(zip(shown, renders, strict=True)):
        row = rows[r]
        left = label(to_bgr(out.image), [f"#{row['rank']} {cams[k].name}", f"S = {row['score']:.4g}"])
        right = label(to_bgr(himg), [f"D_g ({metric}), 0..{vmax:.3g} 1/s"])
        path = png_dir / f"rank{row['rank']:03d}_{row['index']:03d}_{cams[k].name}.png"
        with atomic_output(path, ".png") as tmp:  # OpenCV picks the format from the suffix
            if not cv2.imwrite(str(tmp), np.hstack([left, right])):
                raise OSError("OpenCV could not write the PNG (choose a writable --png-dir)")


def check_some_divergence(result, metric: str, where) -> np.ndarray:
    """The per-Gaussian metric of ``result``; ValueError when it is 0 for every Gaussian (no probe fluid reached
    them: every view would score 0 and the ranking would be the cameras' order)."""
    values = np.asarray(metric_values(result, metric))
    if np.any(values > 0):
        return values
    notes = "; ".join(f"probe {d}: {w}" for d, ws in result.warnings.items() for w in ws)
    raise ValueError(f"{where}: D_g ({metric}) is 0 for every one of the {len(values)} Gaussians, so every view "
                     f"would score 0{' (' + notes + ')' if notes else ''}; re-run `fluidgs simulate` with a smaller "
                     "--dt, or check --scale and --up")


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.output import check_not_input
    from nbv.physics import ProbeDiverged

    all_cams = load_cameras(args.cameras, args.res)
    config = physics_config_from_args(args, cameras=all_cams)
    output = check_output_file(args.output, (".json",))
    if args.top_k is not None and args.top_k < 1:
        raise ValueError(f"--top-k must be >= 1, got {args.top_k}")
    if args.png_top < 1:
        raise ValueError(f"--png-top must be >= 1 view, got {args.png_top}; use --no-png for no PNGs")
    png_dir = None if args.no_png else (args.png_dir or output.with_name(output.stem + "_views"))
    check_not_input({"-o": output, "--save-result": args.save_result, "--png-dir": png_dir},
                    {"GAUSSIANS": args.gaussians, "--cameras": args.cameras, "--result": args.result})
    if png_dir is not None:
        check_output_file(png_dir / "view.png", (".png",))
    if args.save_result is not None:
        check_output_file(args.save_result, (".h5", ".hdf5"))
    if args.result is None and args.metric not in ("max", "mean") and args.metric not in config.directions:
        raise ValueError(f"--metric {args.metric} needs that probe in --directions ({','.join(config.directions)})")
    record = record_config_from_args(args, config)
    if record is not None and (args.result is not None or args.save_result is None):
        raise ValueError("--record-probe records into the RESULT.h5 of a fresh simulation: pass --save-result "
                         "RESULT.h5" + (" and drop --result" if args.result is not None else ""))
    gaussians = load_gaussians_checked(args.gaussians)
    idx = parse_candidates(args.candidates, len(all_cams))
    cams = [render_size(all_cams[i], args.render_width) for i in idx]
    visible_centres = check_cameras_see(gaussians, cams, [c.name for c in cams])
    try:
        result = obtain_result(args, gaussians, config, record)
    except ProbeDiverged as exc:
        return save_diverged(exc, args.save_result)
    check_some_divergence(result, args.metric, args.result or args.gaussians)
    rows = score_views(gaussians, cams, idx, result, args.metric, png_dir, weighted=not args.unweighted,
                       occlusion=args.occlusion, device=args.device, visible_centres=visible_centres,
                       png_top=None if args.png_all else args.png_top)
    print_table(rows, args.top_k)
    write_json(output, {"cameras": str(args.cameras), "gaussians": str(args.gaussians), "metric": args.metric,
                        "weighted": not args.unweighted, "occlusion": args.occlusion, "dbar_m4_s": result.dbar,
                        "dbar_empty_m4_s": result.dbar_empty, "views": rows, "config": result.config.to_dict()})
    print(f"scores: {output}" + (f"\nviews: {png_dir}" if png_dir is not None else ""))
    h5 = args.result or args.save_result
    if h5 is not None:
        print(f"see them in a browser: fluidgs view {h5} --gaussians {args.gaussians} --scores {output}")
    return 0
