"""Evaluation of a finished active run (paper Sec. 4.1-4.4): visual metrics, D-bar, Chamfer, critical views.

For ``RUN/gaussians.ply`` against the run's dataset (the test split, at the run's resolution):

- **Visual**: mean PSNR (dB) and SSIM over the test views (renders over the dataset background, the metrics of
  :func:`recon.train.evaluate`); LPIPS (AlexNet) when :func:`recon.metrics.lpips_available`, else "unavailable"
  with the reason.
- **Geometry divergence**: one run of the probes (:func:`nbv.physics.simulate_gaussians`, five directions by default)
  gives D-bar = (1/|G|) sum_g pi s_g^2 D_g (D_g = max over the probes), the empty-scene D-bar (the same probes
  without the solid, accumulated onto the same Gaussians) and, for the per-direction ablation, D-bar of every
  probe's own D_g^(IC).
- **Chamfer distance** to the reference mesh (``Dataset.mesh_path``, same frame, scene units): between the centres of
  the Gaussians with opacity > ``chamfer_opacity`` (0.5) and ``chamfer_samples`` points sampled uniformly (by area,
  seeded) on the mesh surface. Centres rather than the solid particles: they need no simulation transform and no
  lattice, so the number depends on the reconstruction alone.
- **Scale**: with the physics config's ``scale="auto"`` and a reference mesh, the scene -> metres scale is pinned to the
  mesh (:func:`fixed_scale`), so D-bar is comparable between the runs of a dataset.
- **Function-critical views** (Sec. 3.4): |P_g| = distinct fluid particles of the ``critical_direction`` (-x) probe
  that came within n r_g of g, taken from the same probe run (it tracks distinct particles); C(T) = sum_g w_g |P_g|
  ranks the test views and the top ``critical_views`` (20) form the subset. Reported: mean PSNR on the subset, and
  D-bar restricted to the Gaussians seen in those views: visible in at least one critical view *and* not hidden
  behind the rendered surface (:func:`nbv.scores.unoccluded`, depth tolerance 3 r_g).
- **Functional error** (with a reference mesh; :mod:`nbv.functional`): the same probes (``functional_directions``,
  -x) against the mesh's solid and the reconstruction's, in the mesh's frame at the pinned scale: the relative error
  of the time-mean force on the solid, beside its noise floor (the mesh on a shifted lattice). The mesh's flows are
  cached, so the runs of one dataset pay for them once.

Writes ``RUN/eval.json`` (all of the above, per view and per direction) and ``RUN/eval.md`` (one Markdown table).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fluidsim.config import check_known_keys
from fluidsim.directions import DIRECTIONS
from nbv.active import ActiveConfig, dataset_up, is_empty_solid
from nbv.active.run_dir import read_run_config
from nbv.io import json_safe, write_json_atomic, write_text_atomic
from nbv.physics import PhysicsConfig, simulate_gaussians
from nbv.scores import critical_scores, critical_subset, geometry_divergence, unoccluded
from nbv.study.calibration import area_weighted_corners
from recon.datasets import load_dataset
from recon.formats import load_gaussians
from recon.mesh_render import load_mesh
from recon.metrics import chamfer_distance, load_lpips, lpips, lpips_unavailable_reason, psnr, ssim
from recon.render import render
from recon.train import view_to

log = logging.getLogger(__name__)

SUMMARY_KEYS = (
    "psnr",
    "ssim",
    "lpips",
    "dbar",
    "dbar_empty",
    "chamfer",
    "critical_psnr",
    "critical_dbar",
    "functional_error",
    "functional_floor",
)


# Upper bounds, checked before any work: a test split holds far fewer views, and 10 M mesh samples are 240 MB of
# points (10^14 asked for petabytes).
MAX_CRITICAL_VIEWS = 100_000
MAX_CHAMFER_SAMPLES = 10_000_000


@dataclass(frozen=True)
class EvalConfig:
    """Evaluation settings.

    Attributes:
        physics: probe settings; None: the run's own physics config over all five probes (with the empty-scene
            reference and distinct-particle tracking switched on).
        critical_views: size of the critical subset (paper: 20).
        critical_direction: the probe whose distinct counts |P_g| rank the views (paper: -x).
        chamfer_samples: points sampled on the reference mesh.
        chamfer_opacity: Gaussians above this opacity enter the Chamfer distance.
        lpips: compute LPIPS when available.
        seed: seed of the mesh samples.
        functional: with a reference mesh, the functional error (:mod:`nbv.functional`): the same probes against
            the mesh's solid and the reconstruction's, in the mesh's frame; its headline and noise floor.
        functional_directions: its probes (default -x, head-on, the paper's functional direction).
    """

    physics: PhysicsConfig | None = None
    critical_views: int = 20
    critical_direction: str = "-x"
    chamfer_samples: int = 20000
    chamfer_opacity: float = 0.5
    lpips: bool = True
    seed: int = 0
    functional: bool = True
    functional_directions: tuple[str, ...] = ("-x",)

    def __post_init__(self) -> None:
        for name, top in (("critical_views", MAX_CRITICAL_VIEWS), ("chamfer_samples", MAX_CHAMFER_SAMPLES)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= top:
                raise ValueError(f"EvalConfig.{name} must be an integer from 1 to {top:,}, got {v!r}")
        if not 0.0 <= self.chamfer_opacity < 1.0:
            raise ValueError(f"EvalConfig.chamfer_opacity must be in [0, 1), got {self.chamfer_opacity!r}")
        if self.critical_direction not in DIRECTIONS:
            raise ValueError(
                f"EvalConfig.critical_direction must be one of {','.join(DIRECTIONS)}, got {self.critical_direction!r}"
            )
        object.__setattr__(self, "functional_directions", tuple(self.functional_directions))
        bad = [d for d in self.functional_directions if d not in DIRECTIONS] or not self.functional_directions
        if bad:
            raise ValueError(
                f"EvalConfig.functional_directions must be a non-empty subset of {','.join(DIRECTIONS)}, got "
                f"{self.functional_directions!r}"
            )
        if self.physics is not None and not isinstance(self.physics, PhysicsConfig):
            raise ValueError(f"EvalConfig.physics must be a PhysicsConfig or None, got {type(self.physics).__name__}")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["physics"] = None if self.physics is None else self.physics.to_dict()
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EvalConfig:
        check_known_keys(cls, data)
        d = dict(data)
        if d.get("physics") is not None and not isinstance(d["physics"], PhysicsConfig):
            d["physics"] = PhysicsConfig.from_dict(d["physics"])
        return cls(**d)


def eval_physics_config(run_physics: PhysicsConfig, config: EvalConfig, up) -> PhysicsConfig:
    """The probe settings of an evaluation: empty reference and distinct tracking on, the run's up direction.

    D-bar is defined over the five probes, so without an explicit ``config.physics`` the evaluation runs all five
    even when the run's selection used fewer (``--directions``, or a ``METHOD@DIR`` experiment method); with one,
    its directions are kept and the critical direction is added when missing.
    """
    if config.physics is not None:
        base = config.physics
        dirs = (
            base.directions
            if config.critical_direction in base.directions
            else tuple(base.directions) + (config.critical_direction,)
        )
    else:
        base, dirs = run_physics, DIRECTIONS
    return replace(base, empty_reference=True, track_distinct=True, up=up, directions=dirs)


def fixed_scale(physics: PhysicsConfig, mesh_path: Path | None) -> PhysicsConfig:
    """Pin ``scale="auto"`` to the reference mesh: metres per unit = target_extent / the mesh's largest extent.

    "auto" would scale every reconstruction by the extent of its own opaque Gaussians, so floaters would change the
    scale and, with s_g in m^2, D-bar by scale^4: runs would not be comparable. With a reference mesh every run of a
    dataset gets the same scale; without one (COLMAP scenes) "auto" stays, and eval.json records the scale used.
    """
    if physics.scale != "auto" or mesh_path is None:
        return physics

    vertices, _ = load_mesh(mesh_path)
    extent = float(np.ptp(np.asarray(vertices, np.float64), axis=0).max())
    if not extent > 0:
        return physics
    return replace(physics, scale=physics.target_extent / extent)


def sample_mesh_surface(vertices: np.ndarray, triangles: np.ndarray, count: int, seed: int = 0) -> np.ndarray:
    """``count`` points uniformly distributed over a triangle mesh's surface (area-weighted, seeded).

    Args:
        vertices: [V, 3]. triangles: [T, 3] vertex indices.
        count: number of points. seed: numpy seed.
    Returns:
        [count, 3] float64.
    """
    v = np.asarray(vertices, np.float64)
    t = np.asarray(triangles, np.int64)
    if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0:
        raise ValueError(f"sample_mesh_surface: triangles must be [T, 3] with T >= 1, got {t.shape}")
    rng = np.random.default_rng(seed)
    a, b, c = area_weighted_corners(v, t, count, rng, "sample_mesh_surface")
    u, w = rng.random(count), rng.random(count)
    flip = u + w > 1.0
    u[flip], w[flip] = 1.0 - u[flip], 1.0 - w[flip]
    return a + u[:, None] * (b - a) + w[:, None] * (c - a)


def chamfer_to_mesh(gaussians, mesh_path: Path, config: EvalConfig) -> dict[str, Any]:
    """Chamfer distance (scene units) between opaque Gaussian centres and points on the reference mesh."""
    keep = gaussians.opacities > config.chamfer_opacity
    if int(keep.sum()) == 0:
        return {"chamfer": None, "reason": f"no Gaussian has opacity > {config.chamfer_opacity}"}
    vertices, triangles = load_mesh(mesh_path)
    surface = sample_mesh_surface(vertices, triangles, config.chamfer_samples, config.seed)
    points = gaussians.means[keep].detach().cpu().double().numpy()
    return {
        "chamfer": chamfer_distance(points, surface),
        "gaussians_used": int(keep.sum()),
        "mesh_samples": config.chamfer_samples,
        "mesh": str(mesh_path),
    }


@torch.no_grad()
def functional_metrics(gaussians, mesh_path: Path, physics: PhysicsConfig, config: EvalConfig) -> dict[str, Any]:
    """The functional error of the reconstruction against the dataset's mesh (:func:`nbv.functional.compare`, its
    headline beside its floor; the reference's flows come from the cache after the first run of a dataset)."""
    from nbv.functional import HEADLINE, FlowCache, FunctionalTarget  # noqa: PLC0415
    from nbv.functional.solids import reference_source  # noqa: PLC0415

    cfg = replace(physics, empty_reference=False, track_distinct=False, directions=config.functional_directions)
    target = FunctionalTarget(reference_source(Path(mesh_path), cfg, None, None), cfg, FlowCache.from_environment())
    try:
        c = target.error(gaussians)
    except ValueError as exc:  # no overlap, an empty solid: the run has no functional error, and says why
        return {"functional_error": None, "functional_floor": None, "reason_functional": str(exc)}
    return {
        "functional_error": c.error,
        "functional_floor": c.floor,
        "functional": {
            "metric": HEADLINE,
            **{k: v for k, v in c.record().items() if k in ("overall", "probes", "overlap", "grids", "warnings")},
        },
    }


def render_test_views(gaussians, views, background, backend: str = "auto") -> tuple[list, list[dict]]:
    """Render every test view; returns (RenderOutputs, per-view {"name", "psnr", "ssim"})."""
    bg = torch.tensor([float(c) for c in background], dtype=torch.float32, device=gaussians.means.device)
    outs, rows = [], []
    for v in views:
        out = render(gaussians, v.camera, bg, backend=backend)
        image = out.image.clamp(0, 1)
        ref = v.image.to(image)
        outs.append(out)
        rows.append({"name": v.name, "psnr": float(psnr(image, ref)), "ssim": float(ssim(image, ref))})
    return outs, rows


def lpips_scores(gaussians, views, renders) -> dict[str, Any]:
    """Mean LPIPS over the views, or {"lpips": "unavailable", "reason": ...}."""
    reason = lpips_unavailable_reason()
    if reason is not None:
        return {"lpips": "unavailable", "reason": reason}
    net = load_lpips(device=gaussians.means.device)
    values = [
        float(lpips(out.image.clamp(0, 1), v.image.to(out.image), net)) for out, v in zip(renders, views, strict=True)
    ]
    return {"lpips": sum(values) / len(values), "per_view": values}


def critical_metrics(gaussians, result, renders, rows, views, config: EvalConfig) -> dict[str, Any]:
    """PSNR and D-bar on the top-k test views by C(T) (see the module docstring)."""
    row = result.directions.index(config.critical_direction)
    distinct = torch.from_numpy(np.asarray(result.per_probe_distinct[row], np.float64))
    c = critical_scores(distinct, renders)
    subset = critical_subset(c, config.critical_views).tolist()
    reach = 3.0 * gaussians.max_radii().detach().cpu().double()
    seen = torch.zeros(gaussians.num, dtype=torch.bool)
    for k in subset:
        seen |= unoccluded(gaussians.means, reach, views[k].camera, renders[k])
    covs = torch.from_numpy(result.covariances)
    d = torch.from_numpy(result.divergence)
    return {
        "critical_psnr": sum(rows[k]["psnr"] for k in subset) / len(subset),
        "critical_dbar": geometry_divergence(covs[seen], d[seen]),
        "critical_views": [views[k].name for k in subset],
        "critical_scores": [float(v) for v in c],
        "critical_gaussians": int(seen.sum()),
        "critical_direction": config.critical_direction,
    }


def physics_metrics(result) -> dict[str, Any]:
    """D-bar, the empty-scene D-bar and the per-direction D-bars of one probe run."""
    covs = torch.from_numpy(result.covariances)

    def per_direction(per_probe) -> dict[str, float] | None:
        if per_probe is None:
            return None
        return {d: geometry_divergence(covs, torch.from_numpy(per_probe[i])) for i, d in enumerate(result.directions)}

    return {
        "dbar": result.dbar,
        "dbar_mean": result.dbar_mean,
        "dbar_empty": result.dbar_empty,
        "dbar_per_direction": per_direction(result.per_probe),
        "dbar_empty_per_direction": per_direction(result.empty_per_probe),
        "solid_particles": int(len(result.solid)),
        "physics_seconds": result.timings.get("total"),
    }


def evaluate_run(
    run_dir: str | Path, config: EvalConfig | None = None, *, device: str = "cpu", progress: bool = True
) -> dict[str, Any]:
    """Evaluate ``RUN/gaussians.ply`` and write ``RUN/eval.json`` and ``RUN/eval.md``.

    Needs an initialised Taichi runtime (the probes).

    Args:
        run_dir: a finished ``fluidgs active`` run folder.
        config: evaluation settings (default :class:`EvalConfig`).
        device: torch device of the renders.
        progress: tqdm bars for the probes.
    Returns:
        The eval.json content; ``summary`` holds the headline numbers (None where not computable).
    Raises:
        ValueError: the folder is not a finished run, or its dataset has no test views.
    """
    config = config or EvalConfig()
    run_dir = Path(run_dir)
    cfg_path, ply = run_dir / "config.json", run_dir / "gaussians.ply"
    if not cfg_path.is_file() or not ply.is_file():
        raise ValueError(
            f"{run_dir} is not a finished active run (needs config.json and gaussians.ply); "
            "run `fluidgs active DATASET -o RUN` first"
        )
    run_cfg = read_run_config(run_dir)
    active = ActiveConfig.from_dict(run_cfg["active"])
    ds = load_dataset(run_cfg["dataset"], resolution=active.resolution)
    if not ds.test:
        raise ValueError(f"{run_cfg['dataset']} has no test views; evaluation needs a test split")
    pcfg = fixed_scale(eval_physics_config(active.physics, config, dataset_up(active.up, ds)), ds.mesh_path)
    t0 = time.perf_counter()
    gaussians = load_gaussians(ply).to(device)
    views = [view_to(v, device) for v in ds.test]
    renders, rows = render_test_views(gaussians, views, ds.background, active.backend)
    out: dict[str, Any] = {
        "run": str(run_dir),
        "dataset": run_cfg["dataset"],
        "method": active.method,
        "seed": active.seed,
        "num_gaussians": gaussians.num,
        "test_views": len(views),
        "config": config.to_dict(),
        "physics_config": pcfg.to_dict(),
        "psnr": sum(r["psnr"] for r in rows) / len(rows),
        "ssim": sum(r["ssim"] for r in rows) / len(rows),
        "per_view": rows,
    }
    out.update(
        lpips_scores(gaussians, views, renders) if config.lpips else {"lpips": "unavailable", "reason": "disabled"}
    )
    if ds.mesh_path is not None:
        out.update(chamfer_to_mesh(gaussians, ds.mesh_path, config))
    else:
        out.update({"chamfer": None, "reason_chamfer": "the dataset has no reference mesh"})
    try:
        result = simulate_gaussians(gaussians.to("cpu"), pcfg, progress=progress, source=str(ply))
    except ValueError as exc:
        if not is_empty_solid(exc):
            raise
        log.warning("%s: %s; no D-bar", run_dir, exc)
        out.update(
            {"dbar": None, "dbar_empty": None, "critical_psnr": None, "critical_dbar": None, "physics_error": str(exc)}
        )
    else:
        out.update(physics_metrics(result))
        out["scale_m_per_unit"] = float(result.transform.scale)
        out.update(critical_metrics(gaussians.to("cpu"), result, renders, rows, views, config))
    if ds.mesh_path is not None and config.functional:
        out.update(functional_metrics(gaussians.to("cpu"), ds.mesh_path, pcfg, config))
    elif config.functional:
        out.update({"functional_error": None, "reason_functional": "the dataset has no reference mesh"})
    out["seconds"] = time.perf_counter() - t0
    out["summary"] = {k: (out.get(k) if isinstance(out.get(k), (int, float)) else None) for k in SUMMARY_KEYS}
    out["summary"]["dbar_per_direction"] = out.get("dbar_per_direction")
    write_json_atomic(run_dir / "eval.json", out)
    text = markdown_line(out)
    write_text_atomic(run_dir / "eval.md", text)
    return json_safe(out)


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None or isinstance(v, str):
        return "n/a" if v is None else v
    if isinstance(v, float) and (abs(v) >= 1e4 or (v != 0 and abs(v) < 1e-3)):
        return f"{v:.3e}"
    return f"{v:.{digits}f}" if math.isfinite(v) else "n/a"


def markdown_line(out: dict[str, Any]) -> str:
    """A Markdown table (header and one row) of the headline metrics."""
    cols = ("method", "seed", *SUMMARY_KEYS)
    cells = [str(out.get("method")), str(out.get("seed"))] + [_fmt(out.get(k)) for k in SUMMARY_KEYS]
    return "| " + " | ".join(cols) + " |\n|" + "---|" * len(cols) + "\n| " + " | ".join(cells) + " |\n"
