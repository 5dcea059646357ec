"""Scoring candidate cameras of a probe run: S(T) (paper Eq. 4-5) per view, ranked, with PNGs of the best views.

S(T) = sum over the Gaussians visible in view T of w_g D_g, with w_g = clamp(pi R_g^2 / (H W), 0, 1) from the
screen-space radii R_g. The radii and visibility come from the projection alone
(:func:`nbv.scores.projected_view_scores`, equal to the renderer's bit for bit), so no candidate is rendered to score
it; full renders are made only for the PNGs (the render beside a D_g heat-map of the same view: the Gaussians
re-coloured by D_g on the TURBO map, rendered with the same camera). This is the library side of `fluidgs score`
and of the demo; `fluidgs critical` and `bench views` use the checks and the device helper.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from nbv.heatmap import color_scale, colored_gaussians
from nbv.io import write_png_atomic
from nbv.lists import parse_list
from nbv.scores import DepthBuffer, projected_counts, projected_view_scores, rank
from recon.render import render
from viz.annotate import label, to_bgr

log = logging.getLogger(__name__)


def torch_device(name: str) -> str:
    """'cuda' when asked for and available, else 'cpu' (with a logged warning)."""
    if name == "cuda" and not torch.cuda.is_available():
        log.warning("--device cuda requested but torch sees no CUDA device; rendering on the CPU")
        return "cpu"
    return name


def parse_candidates(text: str | None, count: int) -> list[int]:
    """``--candidates``: '0,3,5' -> camera indices (all ``count`` when None), by the one list parser
    (:func:`nbv.lists.parse_list`); ValueError naming --candidates on an empty list, a non-integer, an out-of-range
    or a repeated entry."""
    if text is None:
        return list(range(count))
    return list(parse_list(text, int, "--candidates", minimum=0, below=count, unique=True, what="camera",
                           empty_hint=f"or leave the option out to score all {count} cameras",
                           range_hint=f"the cameras file has {count} cameras (0..{count - 1})"))


def render_size(cam, max_width: int):
    """The camera scaled down so its width is at most ``max_width`` pixels (``--render-width``; >= 8)."""
    if max_width < 8:
        raise ValueError(f"--render-width must be >= 8 pixels, got {max_width}")
    return cam.scaled(max_width / cam.width) if cam.width > max_width else cam


def check_cameras_see(gaussians, cameras, names: list[str]) -> np.ndarray:
    """[C] projected centre counts per camera; ValueError when no camera sees any Gaussian (checked before
    simulating), a logged warning for each camera that sees none."""
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
    """[N] the per-Gaussian metric (1/s) of a PhysicsResult: ``metric`` "max" or "mean" (D_g max or mean over the
    probes) or a probe of the result ("-x", ...: that probe's D_g)."""
    if metric == "max":
        return result.divergence
    if metric == "mean":
        return result.divergence_mean
    if metric not in result.directions:
        raise ValueError(f"--metric {metric}: the result has no probe {metric} (it has {','.join(result.directions)})")
    return result.per_probe[result.directions.index(metric)]


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


def score_views(gaussians, cams, idx: list[int], result, metric: str = "max", png_dir: Path | None = None, *,
                weighted: bool = True, occlusion: bool = False, device: str = "cpu",
                visible_centres=None, progress: bool = True, png_top: int | None = 5) -> list[dict]:
    """Score the candidates from the projection alone, rank them and render PNGs of the best ones.

    Args:
        gaussians: the GaussianSet (scene units). cams: the candidate cameras; idx: their indices in the file.
        result: a PhysicsResult of these Gaussians. metric: see :func:`metric_values`.
        png_dir: folder for ``rank<r>_<index>_<name>.png`` (render | D_g heat-map), or None.
        weighted: Eq. 5 weights. occlusion: the coarse depth test (:class:`nbv.scores.DepthBuffer`).
        device: torch device. visible_centres: [C] projected-centre counts for the rows.
        png_top: PNGs for the best ``png_top`` views only (None: every view).
    Returns:
        rows (best first): rank, index, name, score, visible (the Gaussians counted; and visible_centres when
        given).

    Example:
        >>> rows = score_views(gaussians, cams, list(range(len(cams))), result)  # doctest: +SKIP
    """
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


def format_table(rows: list[dict], top_k: int | None = None, value: str = "score") -> str:
    """The ranked rows as a text table (rank, index, name, ``value``, visible), the best ``top_k`` only when given."""
    shown = rows if top_k is None else rows[:top_k]
    lines = [f"{'rank':>4}  {'index':>5}  {'name':<24} {value:>14}  {'visible':>8}"]
    lines += [f"{r['rank']:>4}  {r['index']:>5}  {r['name'][:24]:<24} {r[value]:>14.6g}  {r['visible']:>8}"
              for r in shown]
    return "\n".join(lines)


def render_candidates(gaussians, cameras, heat_gaussians=None, device: str = "cpu", progress: bool = True):
    """Render every camera; yields (RenderOutput with radii/visible on the CPU, heat-map image or None)."""
    dev = torch.device(device)
    g = gaussians.detach().to(dev)
    heat = heat_gaussians.detach().to(dev) if heat_gaussians is not None else None
    with torch.no_grad():
        for cam in tqdm(cameras, desc="render", unit="view", disable=not progress):
            out = render(g, cam, background=1.0)
            himg = render(heat, cam, background=0.0).image if heat is not None else None
            yield out, himg


def _bgr(image: torch.Tensor) -> np.ndarray:
    return to_bgr(image.detach().cpu().numpy())


def write_view_pngs(gaussians, cams, shown: list[int], rows: list[dict], values, metric: str, png_dir: Path,
                    device: str, progress: bool) -> None:
    """Render the views ``shown`` (positions in ``cams``, best first) and write render | D_g heat-map PNGs."""
    vmax = color_scale(values)
    heat = colored_gaussians(gaussians, values, vmax=vmax)
    png_dir.mkdir(parents=True, exist_ok=True)
    renders = render_candidates(gaussians, [cams[k] for k in shown], heat, device, progress)
    for r, (k, (out, himg)) in enumerate(zip(shown, renders, strict=True)):
        row = rows[r]
        left = label(_bgr(out.image), [f"#{row['rank']} {cams[k].name}", f"S = {row['score']:.4g}"])
        right = label(_bgr(himg), [f"D_g ({metric}), 0..{vmax:.3g} 1/s"])
        path = png_dir / f"rank{row['rank']:03d}_{row['index']:03d}_{cams[k].name}.png"
        write_png_atomic(path, np.hstack([left, right]))
