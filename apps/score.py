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
import json
import logging
import math
import os
from pathlib import Path

import numpy as np

from .simulate import (
    add_physics_arguments,
    check_output_file,
    load_gaussians_checked,
    physics_config_from_args,
    write_json,
)

log = logging.getLogger("fluidgs")
METRICS = ("max", "mean", "-x", "+x", "-z", "+z", "-y")


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
    p.add_argument("gaussians", type=Path, help="3DGS Gaussians (.ply or .npz), scene units")
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
                   help="count only Gaussians not hidden behind the rendered surface (depth test; not in the paper, "
                        "whose visibility is frustum culling)")
    p.add_argument("--png-dir", type=Path, default=None,
                   help="folder for the per-view PNGs (default: next to the output, <stem>_views)")
    p.add_argument("--no-png", action="store_true", help="skip the per-view PNGs")
    add_physics_arguments(p)


def load_cameras(path: Path, res: int | None = None) -> list:
    """Cameras of a Blender/NeRF ``transforms.json`` (camera part only; images are not loaded).

    Raises:
        ValueError: naming the file and the key when something is missing or malformed.
    """
    import cv2
    import torch

    from recon.camera import Camera

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"cameras file {p} does not exist; pass a Blender transforms.json")
    try:
        meta = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{p} is not JSON ({exc}); pass a Blender transforms.json") from exc
    frames = meta.get("frames") if isinstance(meta, dict) else None
    if not frames:
        raise ValueError(f"{p}: no 'frames' list; a transforms.json needs frames with 'transform_matrix'")
    cams = []
    gl_to_cv = np.diag([1.0, -1.0, -1.0, 1.0])
    for i, fr in enumerate(frames):
        get = lambda k, fr=fr: fr.get(k, meta.get(k))  # noqa: E731 - frame keys override file keys
        if "transform_matrix" not in fr:
            raise ValueError(f"{p}: frame {i} has no 'transform_matrix'")
        c2w = np.asarray(fr["transform_matrix"], np.float64)
        if c2w.shape == (3, 4):
            c2w = np.vstack([c2w, [0, 0, 0, 1.0]])
        if c2w.shape != (4, 4) or not np.isfinite(c2w).all():
            raise ValueError(f"{p}: frame {i} 'transform_matrix' must be a finite 4x4 matrix")
        w, h = get("w"), get("h")
        name = Path(str(fr.get("file_path", f"view_{i:03d}"))).stem
        if w is None or h is None:
            img = None
            if "file_path" in fr:
                base = p.parent / str(fr["file_path"])
                for cand in (base, Path(str(base) + ".png")):
                    if cand.is_file():
                        img = cv2.imread(str(cand), cv2.IMREAD_UNCHANGED)
                        break
            if img is not None:
                h, w = img.shape[:2]
            elif res is not None:
                w, h = res, res
            else:
                raise ValueError(f"{p}: frame {i} has no 'w'/'h' keys and no readable image; pass --res WIDTH")
        w0, h0 = int(w), int(h)
        w, h = (res, max(1, round(res * h0 / w0))) if res is not None else (w0, h0)
        if get("fl_x") is not None:
            fx = float(get("fl_x")) * w / w0
        elif get("camera_angle_x") is not None:
            angle = float(get("camera_angle_x"))
            if not 0 < angle < math.pi:
                raise ValueError(f"{p}: 'camera_angle_x' must be in (0, pi) radians, got {angle}")
            fx = 0.5 * w / math.tan(0.5 * angle)
        else:
            raise ValueError(f"{p}: missing 'camera_angle_x' (radians) or 'fl_x' (pixels) for frame {i}")
        fy = float(get("fl_y")) * h / h0 if get("fl_y") is not None else fx
        cx = float(get("cx")) * w / w0 if get("cx") is not None else w / 2.0
        cy = float(get("cy")) * h / h0 if get("cy") is not None else h / 2.0
        w2c = np.linalg.inv(c2w @ gl_to_cv)
        try:
            cams.append(Camera(w, h, fx, fy, cx, cy, torch.from_numpy(w2c), name=name))
        except ValueError as exc:
            raise ValueError(f"{p}: frame {i}: {exc}") from exc
    return cams


def parse_candidates(text: str | None, count: int) -> list[int]:
    """'0,3,5' -> indices (all when None); ValueError naming --candidates on bad or out-of-range entries."""
    if text is None:
        return list(range(count))
    try:
        idx = [int(s) for s in text.split(",") if s.strip()]
    except ValueError as exc:
        raise ValueError(f"--candidates must be a comma list of camera indices, got {text!r}") from exc
    bad = [i for i in idx if not 0 <= i < count]
    if bad or not idx:
        raise ValueError(f"--candidates {bad or text!r} out of range: the cameras file has {count} cameras "
                         f"(0..{count - 1})")
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


def obtain_result(args, gaussians, config):
    """PhysicsResult from --result, or a fresh simulation (then saved to --save-result when given)."""
    from nbv.physics import check_result_matches, load_result, save_result, simulate_gaussians

    from .runtime import init_taichi

    if args.result is not None:
        result = load_result(args.result)
        check_result_matches(result, gaussians.num, args.result)
        return result
    init_taichi(args.device, config.precision, args.threads)
    result = simulate_gaussians(gaussians, config, progress=True, source=str(args.gaussians))
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
                visible_centres=None, progress: bool = True) -> list[dict]:
    """Render the candidates, score them with the chosen per-Gaussian metric and write the per-view PNGs.

    Args:
        gaussians: the GaussianSet (scene units). cams: the candidate cameras; idx: their indices in the file.
        result: a PhysicsResult of these Gaussians. metric: see --metric.
        png_dir: folder for ``rank<r>_<index>_<name>.png`` (render | D_g heat-map), or None.
        weighted: Eq. 5 weights. occlusion: depth-tested visibility (:func:`nbv.scores.unoccluded`).
        device: torch device for rendering. visible_centres: [C] projected-centre counts for the rows.
    Returns:
        rows (best first): rank, index, name, score, visible (and visible_centres when given).
    """
    import cv2
    import torch

    from nbv.heatmap import color_scale, colored_gaussians
    from nbv.scores import rank, unoccluded, view_scores

    values = metric_values(result, metric)
    vmax = color_scale(values)
    heat = colored_gaussians(gaussians, values, vmax=vmax) if png_dir is not None else None
    renders, images = [], []
    for out, himg in render_candidates(gaussians, cams, heat, torch_device(device), progress):
        renders.append(out)
        images.append((out.image, himg) if png_dir is not None else None)
    vis = None
    if occlusion:
        reach = 3.0 * gaussians.max_radii().double()
        vis = torch.stack([unoccluded(gaussians.means, reach, c, o) for c, o in zip(cams, renders, strict=True)])
    s = view_scores(torch.from_numpy(np.asarray(values)), renders, weighted=weighted, visible=vis)
    order = rank(s).tolist()
    ranks = {i: r + 1 for r, i in enumerate(order)}
    counted = torch.stack([o.visible.cpu() for o in renders]) if vis is None else vis
    rows = []
    for k in order:
        row = {"rank": ranks[k], "index": idx[k], "name": cams[k].name, "score": float(s[k]),
               "visible": int(counted[k].sum())}
        if visible_centres is not None:
            row["visible_centres"] = int(visible_centres[k])
        rows.append(row)
    if png_dir is not None:
        png_dir.mkdir(parents=True, exist_ok=True)
        for k in order:
            rgb, himg = images[k]
            left = label(to_bgr(rgb), [f"#{ranks[k]} {cams[k].name}", f"S = {float(s[k]):.4g}"])
            right = label(to_bgr(himg), [f"D_g ({metric}), 0..{vmax:.3g} 1/s"])
            path = png_dir / f"rank{ranks[k]:03d}_{idx[k]:03d}_{cams[k].name}.png"
            tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.png")
            if not cv2.imwrite(str(tmp), np.hstack([left, right])):
                raise OSError(f"cannot write {path}; choose a writable --png-dir")
            os.replace(tmp, path)
    return rows


def run_command(args: argparse.Namespace) -> int:
    config = physics_config_from_args(args)
    output = check_output_file(args.output, (".json",))
    if args.top_k is not None and args.top_k < 1:
        raise ValueError(f"--top-k must be >= 1, got {args.top_k}")
    png_dir = None if args.no_png else (args.png_dir or output.with_name(output.stem + "_views"))
    if png_dir is not None:
        check_output_file(png_dir / "view.png", (".png",))
    if args.save_result is not None:
        check_output_file(args.save_result, (".h5", ".hdf5"))
    if args.result is None and args.metric not in ("max", "mean") and args.metric not in config.directions:
        raise ValueError(f"--metric {args.metric} needs that probe in --directions ({','.join(config.directions)})")
    gaussians = load_gaussians_checked(args.gaussians)
    all_cams = load_cameras(args.cameras, args.res)
    idx = parse_candidates(args.candidates, len(all_cams))
    cams = [render_size(all_cams[i], args.render_width) for i in idx]
    visible_centres = check_cameras_see(gaussians, cams, [c.name for c in cams])
    result = obtain_result(args, gaussians, config)
    rows = score_views(gaussians, cams, idx, result, args.metric, png_dir, weighted=not args.unweighted,
                       occlusion=args.occlusion, device=args.device, visible_centres=visible_centres)
    print_table(rows, args.top_k)
    write_json(output, {"cameras": str(args.cameras), "gaussians": str(args.gaussians), "metric": args.metric,
                        "weighted": not args.unweighted, "occlusion": args.occlusion, "dbar_m4_s": result.dbar,
                        "dbar_empty_m4_s": result.dbar_empty, "views": rows, "config": result.config.to_dict()})
    print(f"scores: {output}" + (f"\nviews: {png_dir}" if png_dir is not None else ""))
    return 0
