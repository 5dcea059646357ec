"""Scoring candidate cameras of a probe run: S(T) (paper Eq. 4-5) per view, ranked, with PNGs of the best views.

S(T) = sum over the Gaussians visible in view T of w_g D_g, with w_g = clamp(pi R_g^2 / (H W), 0, 1) from the
screen-space radii R_g. The radii and visibility come from the projection alone
(:func:`nbv.scores.projected_view_scores`, equal to the renderer's bit for bit), so no candidate is rendered to score
it; full renders are made only for the PNGs (the render beside a D_g heat-map of the same view: the Gaussians
re-coloured by D_g on the TURBO map, rendered with the same camera). This is the library side of `fluidgs score`
(:class:`ScoreSettings`, :func:`rank_views`, the views folder of :func:`write_views_folder` and the scores.json of
:func:`scores_record`) and of the demo (:func:`score_views`); `fluidgs critical` and `bench views` use the checks.
"""

from __future__ import annotations

import logging
import re
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm import tqdm

from nbv.coverage import format_number, ranking_agreement, view_parts
from nbv.heatmap import (
    color_scale,
    colored_gaussians,
    composited_values,
    over_range_marks,
    uncertainty_image,
    uncertainty_png,
    unreached_pixels,
    value_layer,
)
from nbv.io import write_atomic, write_png_atomic
from nbv.lists import parse_list
from nbv.scores import DepthBuffer, geometry_divergences, projected_counts, projected_view_scores, rank
from recon.device import torch_device
from recon.render import render_layers
from viz.annotate import label, to_bgr
from viz.cameras import view_file_stem

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ScoreSettings:
    """How the candidates are scored (recorded in scores.json).

    Attributes:
        metric: the per-Gaussian metric: D_g max or mean over the probes, or one probe's (:func:`metric_values`).
        weighted: Eq. 5 weights w_g (False: the plain sum of D_g over the counted Gaussians).
        occlusion: the coarse depth test (:class:`nbv.scores.DepthBuffer`); False: the paper's frustum culling.
        device: torch device of the projection and the renders.
    """

    metric: str = "max"
    weighted: bool = True
    occlusion: bool = True
    device: str = "cpu"

    def record(self) -> dict:
        """The settings as scores.json records them: ``metric``, ``weighted``, ``occlusion``."""
        return {"metric": self.metric, "weighted": self.weighted, "occlusion": self.occlusion}


def parse_candidates(text: str | None, count: int) -> list[int]:
    """``--candidates``: '0,3,5' -> camera indices (all ``count`` when None), by the one list parser
    (:func:`nbv.lists.parse_list`); ValueError naming --candidates on an empty list, a non-integer, an out-of-range
    or a repeated entry."""
    if text is None:
        return list(range(count))
    return list(
        parse_list(
            text,
            int,
            "--candidates",
            minimum=0,
            below=count,
            unique=True,
            what="camera",
            empty_hint=f"or leave the option out to score all {count} cameras",
            range_hint=f"the cameras file has {count} cameras (0..{count - 1})",
        )
    )


def render_size(cam, max_width: int):
    """The camera scaled down so its width is at most ``max_width`` pixels (``--render-width``; >= 8)."""
    if max_width < 8:
        raise ValueError(f"--render-width must be >= 8 pixels, got {max_width}")
    return cam.scaled(max_width / cam.width) if cam.width > max_width else cam


def check_cameras_see(gaussians, cameras, names: list[str], at_most: int | None = None) -> np.ndarray:
    """[C] projected centre counts per camera (:func:`nbv.scores.projected_counts`, each at most ``at_most``: 1 asks
    only whether a camera sees any, usually from one block of centres); ValueError when no camera sees any Gaussian
    (checked before simulating), a logged warning for each camera that sees none."""
    counts = projected_counts(gaussians.means, cameras, at_most=at_most).numpy()
    if counts.max(initial=0) == 0:
        raise ValueError(
            f"none of the {len(cameras)} candidate cameras sees any Gaussian (all centres are behind "
            "them or outside the image); check that the cameras and the Gaussians share one frame "
            "and scale"
        )
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
    raise ValueError(
        f"{where}: D_g ({metric}) is 0 for every one of the {len(values)} Gaussians, so every view "
        f"would score 0{' (' + notes + ')' if notes else ''}; re-run `fluidgs simulate` with a smaller "
        "--dt, or check --scale and --up"
    )


def project_scores(
    gaussians, cams, values, *, weighted: bool = True, occlusion: bool = True, device: str = "cpu", centres=False
):
    """S(T), the coverage A(T) and the counted Gaussians of every camera from the projection alone
    (:func:`nbv.scores.projected_view_scores`; ``occlusion``: the coarse depth test, else frustum culling; ``centres``:
    also the centres inside each view, from the same projection)."""
    start = time.perf_counter()
    scored = projected_view_scores(
        torch.from_numpy(np.asarray(values, np.float64)),
        gaussians.detach().to(torch.device(torch_device(device))),
        cams,
        weighted=weighted,
        depth_buffer=DepthBuffer() if occlusion else None,
        centres=centres,
    )
    seconds = time.perf_counter() - start
    log.info("scored %d views of %d Gaussians from the projection in %.2f s", len(cams), gaussians.num, seconds)
    return scored


def replicas_view_agreement(
    replicas, values, gaussians, cams, idx: list[int], *, weighted: bool = True, occlusion: bool = True, device="cpu"
) -> dict:
    """``agreement["replicas"]`` of a ranking: each replica's view scores from its own per-Gaussian metric
    (``values`` [N, G], e.g. :meth:`nbv.physics.replicas.ReplicaRuns.metric_values`), then
    :func:`nbv.physics.replicas.replica_agreement` (their view rankings, physics parts S/A and D_g, pairwise; the
    coverage A(T) does not depend on the metric, so replica 0's is every replica's)."""
    from nbv.physics.replicas import replica_agreement  # noqa: PLC0415 - loads the physics (Taichi) only when used

    scored = [
        project_scores(gaussians, cams, v, weighted=weighted, occlusion=occlusion, device=device)
        for v in np.asarray(values, np.float64)
    ]
    per = np.stack([sc.scores.numpy() for sc in scored])
    return replica_agreement(replicas, per, idx, coverage=scored[0].coverage.numpy())


def ranked_rows(scored, cams, idx: list[int], value: str = "score", visible_centres=None) -> list[dict]:
    """Rows of a :class:`nbv.scores.ProjectedScores`, best first: rank, index, name, ``value`` (S(T)), coverage
    A(T), physics_mean S/A, coverage_rank, physics_rank, visible (the Gaussians counted; and visible_centres when
    given)."""
    s = scored.scores
    parts = view_parts(s.numpy(), scored.coverage.numpy())
    rows = []
    for k in rank(s).tolist():
        row = {
            "rank": parts[k]["rank"],
            "index": idx[k],
            "name": cams[k].name,
            value: float(s[k]),
            **{key: parts[k][key] for key in ("coverage", "physics_mean", "coverage_rank", "physics_rank")},
            "visible": int(scored.counted[k]),
        }
        if visible_centres is not None:
            row["visible_centres"] = int(visible_centres[k])
        rows.append(row)
    return rows


def rows_agreement(rows: list[dict], value: str = "score") -> dict:
    """:func:`nbv.coverage.ranking_agreement` of ranked rows (their ``value`` against their coverage)."""
    return ranking_agreement([r[value] for r in rows], [r["coverage"] for r in rows])


def rank_views(
    gaussians, cams, idx: list[int], result, values, settings: ScoreSettings, visible_centres=None, centres=False
):
    """Score the candidates from the projection alone and rank them, with how far coverage decides the ranking.

    Args:
        gaussians: the GaussianSet (scene units). cams: the candidate cameras; idx: their indices in the file.
        result: the PhysicsResult ``values`` come from. values: [G] the settings' metric (:func:`metric_values`);
            with replica runs in ``result``, each replica's own metric is ranked too.
        settings: metric, weights, visibility test, device. visible_centres: [C] projected-centre counts for the rows.
        centres: without ``visible_centres``, count them while scoring (the same numbers as
            :func:`nbv.scores.projected_counts`, from the projection the scores make anyway).
    Returns:
        (the :class:`nbv.scores.ProjectedScores`, the rows best first (:func:`ranked_rows`), their agreement
        (:func:`rows_agreement`; with replica runs also ``replicas``: each replica's ranking against the others,
        :func:`replicas_view_agreement`)).
    """
    how = {"weighted": settings.weighted, "occlusion": settings.occlusion, "device": settings.device}
    scored = project_scores(gaussians, cams, values, **how, centres=centres and visible_centres is None)
    if visible_centres is None:
        visible_centres = scored.centres
    rows = ranked_rows(scored, cams, idx, visible_centres=visible_centres)
    agreement = rows_agreement(rows)
    if result.replicas is not None:  # each replica's own ranking, against the others
        per_replica = result.replicas.metric_values(settings.metric, result.directions)
        agreement["replicas"] = replicas_view_agreement(result.replicas, per_replica, gaussians, cams, idx, **how)
    return scored, rows, agreement


def best_views(scored, top: int | None) -> list[int]:
    """Positions of the best ``top`` candidates by S(T) (None: every candidate), best first: the views a views
    folder shows."""
    return rank(scored.scores).tolist()[:top]


def score_views(
    gaussians,
    cams,
    idx: list[int],
    result,
    metric: str = "max",
    png_dir: Path | None = None,
    *,
    weighted: bool = True,
    occlusion: bool = True,
    device: str = "cpu",
    visible_centres=None,
    progress: bool = True,
    png_top: int | None = 5,
) -> list[dict]:
    """Score the candidates from the projection alone, rank them and render PNGs of the best ones.

    Args:
        gaussians, cams, idx, result, visible_centres: as in :func:`rank_views`. metric: see :func:`metric_values`.
        png_dir: folder for ``rank<r>_<index>_<name>.png`` (render | D_g heat-map), or None.
        weighted, occlusion, device: as in :class:`ScoreSettings`.
        png_top: PNGs for the best ``png_top`` views only (None: every view).
    Returns:
        the rows best first (:func:`ranked_rows`).

    Example:
        >>> rows = score_views(gaussians, cams, list(range(len(cams))), result)  # doctest: +SKIP
        >>> print(coverage_line(rows_agreement(rows)))  # doctest: +SKIP
    """
    values = metric_values(result, metric)
    scored = project_scores(gaussians, cams, values, weighted=weighted, occlusion=occlusion, device=device)
    rows = ranked_rows(scored, cams, idx, visible_centres=visible_centres)
    if png_dir is not None:
        shown = best_views(scored, png_top)
        write_view_pngs(
            gaussians, cams, shown, rows, values, metric, png_dir, torch_device(device), progress, result.reached
        )
    return rows


def format_table(rows: list[dict], top_k: int | None = None, value: str = "score") -> str:
    """The ranked rows as a text table: rank, index, name, ``value`` (S), the coverage A and the physics part S/A
    with their ranks, and the Gaussians counted; the best ``top_k`` only when given. The numbers carry
    :data:`nbv.coverage.SCORE_DIGITS` significant digits."""
    head = {"score": "S", "critical_score": "C"}.get(value, value)
    lines = [
        f"{'rank':>4}  {'index':>5}  {'name':<24} {head:>9}  {'A':>9} {'A#':>4}  {head + '/A':>9} "
        f"{head + '/A#':>5}  {'visible':>8}"
    ]
    for r in rows[:top_k]:
        lines.append(
            f"{r['rank']:>4}  {r['index']:>5}  {r['name'][:24]:<24} {format_number(r[value]):>9}  "
            f"{format_number(r.get('coverage')):>9} {r.get('coverage_rank') or '-':>4}  "
            f"{format_number(r.get('physics_mean')):>9} {r.get('physics_rank') or '-':>5}  "
            f"{r['visible']:>8}"
        )
    return "\n".join(lines)


def write_view_pngs(
    gaussians,
    cams,
    shown: list[int],
    rows: list[dict],
    values,
    metric: str,
    png_dir: Path,
    device: str,
    progress: bool,
    reached: np.ndarray | None = None,
) -> None:
    """Render the views ``shown`` (positions in ``cams``, best first) and write render | D_g heat-map PNGs.

    The heat-map colours each Gaussian up to the 99th percentile v_max of the values (of the ``reached`` ones [N]
    bool; the others are grey: no fluid measured them); where the Gaussians above it make up most of a pixel (their
    composited share > 1/2), the panel is marked "+": its colour is clipped there."""
    v = np.asarray(values, np.float64)
    vmax = color_scale(v if reached is None else v[np.asarray(reached, bool)])
    heat = colored_gaussians(gaussians, values, vmax=vmax, reached=reached)
    over = (v > vmax).astype(np.float64)
    png_dir.mkdir(parents=True, exist_ok=True)
    dev = torch.device(device)
    layers = [gaussians.detach().to(dev), heat.detach().to(dev)]
    backgrounds = [1.0, 0.0]
    top = None
    if over.any():  # the "+" marks: the composited share of the Gaussians above v_max, in the same pass
        over_layer, top = value_layer(layers[0], over)
        layers.append(over_layer)
        backgrounds.append(0.0)
    legend = [f"D_g ({metric}), 0..{vmax:.3g}+ 1/s", "+: above" + ("" if reached is None else ", grey: not reached")]
    for k, row in zip(tqdm(shown, desc="render", unit="view", disable=not progress), rows, strict=False):
        with torch.no_grad():  # the three images share one projection and one pairing (recon.render.render_layers)
            outs = render_layers(layers, cams[k], backgrounds)
        render, heat_bgr = (to_bgr(o.image.detach().cpu().numpy()) for o in outs[:2])
        left = label(
            render,
            [
                f"#{row['rank']} {cams[k].name}",
                f"S = {format_number(row['score'])}",
                f"A = {format_number(row.get('coverage'))}, S/A = {format_number(row.get('physics_mean'))}",
            ],
        )
        if top is not None:
            share, _ = composited_values(outs[2], top)
            mask = cv2.resize(
                (share > 0.5).astype(np.uint8), (heat_bgr.shape[1], heat_bgr.shape[0]), interpolation=cv2.INTER_NEAREST
            ).astype(bool)
            heat_bgr = over_range_marks(heat_bgr, mask)
        right = label(heat_bgr, legend)
        path = png_dir / f"{view_file_stem(row['rank'], row['index'], cams[k].name)}.png"
        write_png_atomic(path, np.hstack([left, right]))


def enlarged(image: np.ndarray, min_width: int = 320) -> np.ndarray:
    """``image`` [H, W] enlarged by the smallest integer factor (nearest neighbour: every pixel stays one value)
    that makes it at least ``min_width`` wide, so that a small view's labels are not clipped."""
    a = np.asarray(image)
    f = max(1, -(-min_width // max(a.shape[1], 1)))
    return np.repeat(np.repeat(a, f, axis=0), f, axis=1) if f > 1 else a


def uncertainty_scale(images: list[np.ndarray], percentile: float = 99.0) -> float:
    """One colour range for a set of uncertainty images: the ``percentile`` of their covered pixels (> 0)."""
    covered = np.concatenate([np.asarray(i, np.float64).reshape(-1) for i in images]) if images else np.zeros(0)
    return color_scale(covered[covered > 0], percentile)


def write_uncertainty_images(
    gaussians,
    cams,
    shown: list[int],
    rows: list[dict],
    values,
    metric: str,
    png_dir: Path,
    device: str,
    reached: np.ndarray | None = None,
) -> dict[int, dict]:
    """Per view ``shown`` (positions in ``cams``, best first): its physics-uncertainty image
    (:func:`nbv.heatmap.uncertainty_image` of the per-Gaussian metric), as float32 ``.npy`` (1/s per pixel) and a
    colour PNG with its scale bar (one range for all views: the 99th percentile of their covered pixels; "+" above;
    grey where Gaussians not ``reached`` ([N] bool) draw most of the pixel, :func:`nbv.heatmap.unreached_pixels`).

    Returns:
        {view index in the cameras file: {"npy": file name, "png": file name}} (names relative to ``png_dir``).
    """
    png_dir.mkdir(parents=True, exist_ok=True)
    images = [uncertainty_image(gaussians, cams[k], values, device)[0] for k in shown]
    vmax = uncertainty_scale(images)
    written = {}
    for k, img, row in zip(shown, images, rows, strict=False):  # rows: every view, best first
        stem = f"{view_file_stem(row['rank'], row['index'], cams[k].name)}_uncertainty"
        write_atomic(png_dir / f"{stem}.npy", lambda tmp, img=img: np.save(tmp, img), suffix=".npy")
        # enlarged: room for the labels, >= 320 px wide
        grey = None if reached is None else enlarged(unreached_pixels(gaussians, cams[k], reached, device))
        picture = label(
            uncertainty_png(enlarged(img), vmax, "1/s", grey),
            [
                f"#{row['rank']} {cams[k].name}: composited D_g ({metric})",
                f"0..{vmax:.3g}+ 1/s" + ("" if grey is None else "; grey: not reached"),
            ],
        )
        write_png_atomic(png_dir / f"{stem}.png", picture)
        written[row["index"]] = {"npy": f"{stem}.npy", "png": f"{stem}.png"}
    return written


# the files of a views folder (:func:`write_view_pngs`, :func:`write_uncertainty_images`): rank001_004_name.png, and
# with the uncertainty images rank001_004_name_uncertainty.png / .npy
VIEW_FILE = re.compile(r"^rank\d{3,}_\d{3,}_.*(\.png|_uncertainty\.npy)$")


def view_files(folder: Path) -> dict[Path, int]:
    """{file: inode} of the files of the views folder's own naming pattern (:data:`VIEW_FILE`) in ``folder``."""
    if not folder.is_dir():
        return {}
    return {p: p.stat().st_ino for p in folder.iterdir() if VIEW_FILE.match(p.name) and p.is_file()}


def remove_stale(earlier: dict[Path, int]) -> list[Path]:
    """Remove the view files an earlier run wrote that this run did not write again (the same inode: every writer
    replaces its file atomically, so a rewritten file has a new one); nothing else in the folder is touched. Returns
    the files removed."""
    stale = [p for p, inode in earlier.items() if p.is_file() and p.stat().st_ino == inode]
    for p in stale:
        p.unlink()
    return stale


def write_views_folder(
    gaussians,
    cams,
    scored,
    rows: list[dict],
    values,
    settings: ScoreSettings,
    png_dir: Path | None,
    *,
    top: int | None = None,
    uncertainty: bool = False,
    reached: np.ndarray | None = None,
) -> tuple[dict[int, dict], list[Path]]:
    """The views folder of a ranking in ``png_dir`` (None: nothing written): the PNGs of the best ``top`` views
    (None: every view; :func:`write_view_pngs`), with ``uncertainty`` also their physics-uncertainty images
    (:func:`write_uncertainty_images`; the Gaussians not ``reached`` grey in both); then the view files of an earlier
    run that this one did not write again are removed (:func:`remove_stale`).

    Returns:
        (the uncertainty images ({} without ``uncertainty``), the stale files removed).
    """
    if png_dir is None:
        return {}, []
    earlier = view_files(png_dir)
    views = (gaussians, cams, best_views(scored, top), rows, values, settings.metric, png_dir)
    device = torch_device(settings.device)
    write_view_pngs(*views, device, True, reached)
    images = write_uncertainty_images(*views, device, reached) if uncertainty else {}
    return images, remove_stale(earlier)


def scores_record(
    rows: list[dict],
    agreement: dict,
    result,
    settings: ScoreSettings,
    cameras: str | Path,
    gaussians: str | Path,
    images: dict[int, dict] | None = None,
    png_dir: Path | None = None,
) -> dict:
    """scores.json of `fluidgs score` (docs/formats.md): the cameras and Gaussians files, the settings, D-bar and
    D-bar_empty, the agreement, the views (``rows``, best first; a view with an uncertainty image of ``images``
    gets its files under ``png_dir`` as ``uncertainty_image``) and the result's config."""
    images = images or {}
    views = [
        {**r, "uncertainty_image": {k: str(png_dir / v) for k, v in images[r["index"]].items()}}
        if r["index"] in images
        else r
        for r in rows
    ]
    return {
        "cameras": str(cameras),
        "gaussians": str(gaussians),
        **settings.record(),
        "dbar_m4_s": result.dbar,
        "dbar_empty_m4_s": result.dbar_empty,
        "agreement": agreement,
        "views": views,
        "config": result.config.to_dict(),
    }


REACHED_WARNING = 0.5  # warn when fewer than this share of the counted Gaussians got any D_g


def _ratio(value: float | None, reference: float | None) -> str:
    if value is None or reference is None or not reference > 0:
        return "n/a (no empty-scene run)"
    return f"x{value / reference:.2g}"


def probe_lines(result) -> list[str]:
    """Per probe of a PhysicsResult, what the fluid reached: D-bar / D-bar_empty of that probe (first), the share
    of the (kept) Gaussians it reached, and its leak counts; then the combined D-bar / D-bar_empty and D-bar."""
    kept = np.ones(result.num_gaussians, bool) if result.kept is None else np.asarray(result.kept, bool)
    total = int(kept.sum())
    empties = [] if result.empty_per_probe is None else list(result.empty_per_probe)
    probes = [torch.from_numpy(np.asarray(p)) for p in [*result.per_probe, *empties]]
    # the weights pi s_g^2 once for all the probes: D-bar of each probe, then of each empty-scene probe
    dbars = geometry_divergences(torch.from_numpy(np.asarray(result.covariances)), probes)
    lines = []
    for i, d in enumerate(result.directions):
        empty = None if result.empty_per_probe is None else dbars[len(result.per_probe) + i]
        reached = int((np.asarray(result.per_probe_counts[i])[kept] > 0).sum())
        leak = result.leaks.get(d)
        if leak is None:
            leaks = ""
        elif leak.max == 0:
            leaks = "; no fluid leaked into the solid"
        else:
            leaks = f"; leaked into the solid: {leak.final} at the end, at most {leak.max} (step {leak.max_step})"
        lines.append(
            f"  probe {d:>3}: D-bar/D-bar_empty {_ratio(dbars[i], empty)}, reached {reached / max(total, 1):.0%} of "
            f"the Gaussians ({reached:,} of {total:,}){leaks}"
        )
    empty = "n/a" if result.dbar_empty is None else f"{result.dbar_empty:.2g}"
    lines.append(
        f"D-bar/D-bar_empty {_ratio(result.dbar, result.dbar_empty)} (D-bar {result.dbar:.2g} m^4/s, "
        f"empty scene {empty})"
    )
    return lines


def reach_warning(values, seen, config, what: str = "D_g", symbol: str = "S") -> str | None:
    """A warning when fewer than half of the Gaussians the views count (``seen`` [N] bool) got any D_g (``values``
    [N] > 0; ``what`` names the metric, ``symbol`` the score), naming the settings that reach more; None
    otherwise."""
    seen = np.asarray(seen, bool)
    counted = int(seen.sum())
    got = int((np.asarray(values)[seen] > 0).sum())
    if counted == 0 or got >= REACHED_WARNING * counted:
        return None
    return (
        f"only {got / counted:.0%} of the {counted:,} Gaussians the views count got any {what} ({got:,}); "
        f"{symbol}(T) rests on the few the fluid reached. Reach more with finer particles (--particle-radius, now "
        f"{config.particle_radius:g} m; each halving gives 8x the particles) or a longer run (--steps, now "
        f"{config.steps})"
    )
