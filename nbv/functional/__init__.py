"""The functional error of a reconstruction: does its solid behave like the reference object in the fluid?

:func:`compare` runs the same probes against the reference's solid and the reconstruction's, and reports per probe
and in all the errors of :mod:`nbv.functional.flow` (the force time series, the time-mean drag and lift, the velocity
field) and the solids' occupancy IoU and Chamfer distance. The probe setups (domain, slab) are laid out once, around
the reference's solid, in one frame (:mod:`nbv.functional.solids`), so both runs see the same fluid.

Beside every figure stands its **noise floor**: the same figure for the reference against itself on a lattice
shifted by a fraction of a spacing (the second replica's offset, :func:`nbv.physics.replicas.replica_offsets`). That
is the error a perfect reconstruction gets from where the particle lattice falls; an error at the floor says
nothing, one well above it says the reconstruction behaves differently.

Cost: three probe runs per direction (the reference, its shifted copy and the reconstruction). The reference's two
are cached on disk (:class:`FlowCache`, keyed by both solids, the setup, the settings and the engine's code), so a
second reconstruction compared with the same reference costs one probe run per direction.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import stat
import time
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from nbv.functional.flow import FlowRecord, SampleGrid, flow_errors, relative_l2, run_flow
from nbv.functional.solids import SolidSource, lattice_keys, resample_cubes
from nbv.physics.config import PhysicsConfig
from nbv.physics.forces import FORCE_WINDOW_S, flow_axis, moving_mean
from nbv.physics.replicas import replica_offsets

log = logging.getLogger(__name__)

METRICS = ("mean_force", "drag", "lift", "force_l2", "velocity_l2")
# the one number of a reconstruction's functional error (eval, experiment, oracle): the time-mean force, drag and lift
# together, the figure farthest above its floor on planted defects (the force series and the velocity field carry
# the impact's timing, which a lattice shift already moves: floors of 30-50 %; docs/results.md)
HEADLINE = "mean_force"
# a floor this high (the reference against itself on a shifted lattice) leaves no room to judge: too few steps for
# the fluid to pass the object, or too coarse a lattice for its size
FLOOR_LIMIT = 0.5
DEFAULT_DIRECTIONS = ("-x",)  # the paper's functional direction: head-on


@dataclass(frozen=True)
class Overlap:
    """Occupancy IoU (lattice cells) and Chamfer distance (m, the mean of both directed mean distances)."""

    iou: float
    chamfer: float


def solid_overlap(a: np.ndarray, b: np.ndarray, spacing: float) -> Overlap:
    """The :class:`Overlap` of two lattice solids (M, 3) m, both taken as the union of their particles' cubes and
    resampled onto the lattice of offset 0 (so two lattices of other offsets compare as shapes, not as point sets)."""
    from scipy.spatial import cKDTree  # noqa: PLC0415

    a, b = resample_cubes(a, spacing, (0, 0, 0)), resample_cubes(b, spacing, (0, 0, 0))  # one lattice for both
    ka, kb = ({tuple(k) for k in lattice_keys(p, spacing, (0, 0, 0))} for p in (a, b))
    union = len(ka | kb)
    iou = len(ka & kb) / union if union else 0.0
    if len(a) == 0 or len(b) == 0:
        return Overlap(float(iou), float("inf"))
    chamfer = 0.5 * (cKDTree(b).query(a)[0].mean() + cKDTree(a).query(b)[0].mean())
    return Overlap(float(iou), float(chamfer))


# ---- the reference's flows, cached --------------------------------------------------------------------------------
CACHE_MAX_BYTES = 512 * 2**20  # an entry larger than this is not read


def _code_digest() -> str:
    """The engine's code the flows depend on (the step, the forces, the sampling), not whole packages."""
    import fluidsim  # noqa: PLC0415

    h = hashlib.sha256()
    root = Path(fluidsim.__file__).parent
    for name in ("solver.py", "forces.py", "dfsph.py", "neighbors.py", "viscosity.py", "passes.py", "probes.py"):
        h.update((root / name).read_bytes())
    h.update(Path(__file__).with_name("flow.py").read_bytes())
    return h.hexdigest()[:16]


class FlowCache:
    """The reference's flows on disk: one ``.npz`` per (solid, setup, settings, grid, code), in
    ``$FLUIDGS_CACHE_DIR/functional`` (default ``~/.cache/fluidgs/functional``).

    It reads only regular files (no link, FIFO or device) under :data:`CACHE_MAX_BYTES`, without pickles, and checks
    every array's shape and finiteness; an entry that fails is ignored and recomputed. It does not protect against a
    writer who can plant a well-formed entry under the right name: such a file is trusted like a run of one's own.
    """

    def __init__(self, folder: Path | None):
        self.folder = folder

    @classmethod
    def from_environment(cls, enabled: bool = True) -> FlowCache:
        if not enabled:
            return cls(None)
        root = os.environ.get("FLUIDGS_CACHE_DIR") or str(Path.home() / ".cache" / "fluidgs")
        return cls(Path(root) / "functional")

    @staticmethod
    def key(solid: np.ndarray, setup, config: PhysicsConfig, grid: SampleGrid) -> str:
        h = hashlib.sha256()
        h.update(np.ascontiguousarray(solid, np.float64).tobytes())
        h.update(repr(setup).encode())
        h.update(json.dumps(config.to_dict(), sort_keys=True, default=str).encode())
        h.update(np.ascontiguousarray(grid.points, np.float64).tobytes())
        h.update(repr(grid.steps).encode())
        h.update(_code_digest().encode())
        return h.hexdigest()[:32]

    def get(self, key: str, steps: int, points: int) -> FlowRecord | None:
        if self.folder is None:
            return None
        path = self.folder / f"{key}.npz"
        try:
            st = os.lstat(path)
        except OSError:
            return None
        if not stat.S_ISREG(st.st_mode) or st.st_size > CACHE_MAX_BYTES:
            log.warning("ignoring the cached flow %s: not a regular file of at most %d bytes", path, CACHE_MAX_BYTES)
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                rec = FlowRecord(z["forces"], z["dt"], z["velocities"])
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
            log.warning("ignoring the cached flow %s: %s", path, exc)
            return None
        ok = (
            rec.forces.shape == (steps, 3)
            and rec.dt.shape == (steps,)
            and rec.velocities.shape[1:] == (points, 3)
            and all(np.isfinite(a).all() for a in (rec.forces, rec.dt, rec.velocities))
            and (rec.dt > 0).all()
        )
        return rec if ok else None

    def put(self, key: str, rec: FlowRecord) -> None:
        if self.folder is None:
            return
        from fluidsim.files import OutputError, atomic_output  # noqa: PLC0415

        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            with atomic_output(self.folder / f"{key}.npz") as tmp, open(tmp, "wb") as fh:
                np.savez(fh, forces=rec.forces, dt=rec.dt, velocities=rec.velocities.astype(np.float32))
        except (OSError, OutputError) as exc:  # a cache that cannot be written costs time, never the result
            log.warning("could not cache the reference flow in %s: %s", self.folder, exc)


# ---- the comparison -----------------------------------------------------------------------------------------------
@dataclass
class Comparison:
    """What :func:`compare` measured.

    Attributes:
        probes: {direction: {metric: value}} of the reconstruction against the reference (:func:`flow_errors`).
        floors: {direction: {metric: value}} of the shifted reference against the reference.
        overall, overall_floor: {metric: value} over every probe (the L2 errors over all the probes' samples, the
            drag and lift errors averaged).
        overlap, overlap_floor: the solids' :class:`Overlap`. flows: {direction: {"reference", "shifted",
            "reconstruction": FlowRecord}}. grids: {direction: SampleGrid}. settings: a JSON-able record.
        warnings: what the inputs made us assume or what the runs showed.
    """

    probes: dict[str, dict[str, float]]
    floors: dict[str, dict[str, float]]
    overall: dict[str, float]
    overall_floor: dict[str, float]
    overlap: Overlap
    overlap_floor: Overlap
    flows: dict[str, dict[str, FlowRecord]]
    grids: dict[str, SampleGrid]
    settings: dict
    warnings: list[str] = field(default_factory=list)

    @property
    def error(self) -> float:
        """The headline functional error (:data:`HEADLINE`): the time-mean force's relative error, over the probes."""
        return self.overall[HEADLINE]

    @property
    def floor(self) -> float:
        return self.overall_floor[HEADLINE]

    def record(self) -> dict:
        """JSON-able: every figure beside its floor, the overlap, the grids and the settings."""
        return {
            "functional_error": {"metric": HEADLINE, "value": self.error, "floor": self.floor},
            "overall": {m: {"value": self.overall[m], "floor": self.overall_floor[m]} for m in METRICS},
            "probes": {
                d: {k: {"value": v, "floor": self.floors[d].get(k)} for k, v in p.items()}
                for d, p in self.probes.items()
            },
            "overlap": {
                "iou": self.overlap.iou,
                "iou_floor": self.overlap_floor.iou,
                "chamfer_m": self.overlap.chamfer,
                "chamfer_floor_m": self.overlap_floor.chamfer,
            },
            "grids": {d: g.describe(self.settings["dt"]) for d, g in self.grids.items()},
            "force_window_s": FORCE_WINDOW_S,
            "settings": self.settings,
            "warnings": self.warnings,
        }


def overall_errors(flows: dict[str, dict[str, FlowRecord]], which: str, per_probe: dict) -> dict[str, float]:
    """The errors over all probes: the L2 ones over every probe's samples stacked, the time-mean ones averaged."""

    def l2(part) -> float:
        return relative_l2(*(np.concatenate([part(f[w]) for f in flows.values()]) for w in (which, "reference")))

    def averaged(metric: str) -> float:
        return float(np.mean([p[metric] for p in per_probe.values()]))

    return {
        "mean_force": averaged("mean_force"),
        "force_l2": l2(lambda r: moving_mean(r.forces, r.dt)),
        "drag": averaged("drag"),
        "lift": averaged("lift"),
        "velocity_l2": l2(lambda r: r.velocities.ravel()),
    }


def check_overlap(overlap: Overlap, reference: SolidSource, recon: SolidSource) -> None:
    """Refuse solids that do not overlap (IoU 0), naming the transform option."""
    if overlap.iou <= 0.0:
        raise ValueError(
            f"the reconstruction {recon.path.name} and the reference {reference.path.name} do not overlap (solid IoU "
            f"0, Chamfer {overlap.chamfer:.3g} m in simulation metres): they are not in one frame; pass "
            "--reference-transform (4 x 4, reference -> reconstruction scene frame) or the same --up for both"
        )


def compare(
    reference: SolidSource,
    recon: SolidSource,
    config: PhysicsConfig,
    directions=DEFAULT_DIRECTIONS,
    progress: bool = True,
    cache: FlowCache | None = None,
    on_overlap=None,
) -> Comparison:
    """The functional error of ``recon`` against ``reference`` with its noise floor (module docstring).

    Args:
        reference, recon: the two solids' sources in one frame (:mod:`nbv.functional.solids`).
        config: probe settings (the particle radius, steps, speed...). directions: the probes.
        progress: a bar over the probe runs with one ETA. cache: the reference's flows (None: not cached).
        on_overlap: called with (overlap, floor overlap) before any probe runs (the command prints it).
    Raises:
        ValueError: solids that do not overlap, before any probe runs.
    """
    from tqdm import tqdm  # noqa: PLC0415

    from fluidsim.probes import probe_setups  # noqa: PLC0415 - Taichi

    cfg = replace(config, directions=tuple(directions))
    spacing = 2.0 * cfg.particle_radius
    shift = replica_offsets(2)[1]
    ref = reference.solid(spacing)
    ref_shifted = reference.solid(spacing, shift)
    rec = recon.solid(spacing)
    for name, pts in (("reference", ref), ("reconstruction", rec)):
        if len(pts) == 0:
            raise ValueError(f"the {name} has no solid particle at r = {cfg.particle_radius} m; check the file")
    overlap, overlap_floor = solid_overlap(rec, ref, spacing), solid_overlap(ref_shifted, ref, spacing)
    check_overlap(overlap, reference, recon)
    if on_overlap is not None:
        on_overlap(overlap, overlap_floor)
    setups = probe_setups(ref, cfg.probe_config(), spacing, cfg.directions)  # laid out once, around the reference
    warnings = list(reference.warnings) + list(recon.warnings) + outside_warnings(rec, setups)
    cache = cache or FlowCache(None)
    flows, grids, probes, floors = {}, {}, {}, {}
    # one bar over the three probe runs of every direction, one ETA
    with tqdm(total=len(cfg.directions) * 3 * cfg.steps, disable=not progress, unit="step", leave=False) as bar:
        runs = _Runs(bar, cfg.steps)
        for d in cfg.directions:
            st = setups[d]
            grids[d] = grid = SampleGrid.around(ref, st.domain_min, st.domain_max, spacing, cfg.steps)
            flows[d] = {
                "reference": runs.cached(cache, ref, st, cfg, grid, f"{d} reference"),
                "shifted": runs.cached(cache, ref_shifted, st, cfg, grid, f"{d} reference, shifted lattice"),
                "reconstruction": runs.run(rec, st, cfg, grid, f"{d} reconstruction"),
            }
            probes[d] = flow_errors(flows[d]["reconstruction"], flows[d]["reference"], d)
            floors[d] = flow_errors(flows[d]["shifted"], flows[d]["reference"], d)
            if not np.any(flows[d]["reconstruction"].forces):
                warnings.append(f"probe {d}: the fluid never reached the reconstruction: its force is 0")
    settings = {
        **run_settings(cfg, shift, reference, recon),
        "solid_particles": {"reference": len(ref), "shifted": len(ref_shifted), "reconstruction": len(rec)},
        "probe_runs": runs.done,
        "cached_runs": runs.hits,
        "seconds": round(runs.seconds, 1),
    }
    return Comparison(
        probes=probes,
        floors=floors,
        overall=overall_errors(flows, "reconstruction", probes),
        overall_floor=overall_errors(flows, "shifted", floors),
        overlap=overlap,
        overlap_floor=overlap_floor,
        flows=flows,
        grids=grids,
        settings=settings,
        warnings=warnings,
    )


def outside_warnings(rec: np.ndarray, setups: dict) -> list[str]:
    """One warning per probe whose domain (laid out around the reference) leaves out reconstruction particles."""
    out = []
    for d, st in setups.items():
        outside = int(((rec < np.asarray(st.domain_min)) | (rec > np.asarray(st.domain_max))).any(1).sum())
        if outside:
            out.append(
                f"probe {d}: {outside} of the reconstruction's {len(rec)} solid particles lie outside the "
                "domain laid out around the reference and are left out"
            )
    return out


def run_settings(cfg: PhysicsConfig, shift, reference: SolidSource, recon: SolidSource) -> dict:
    """The JSON record of what a comparison ran: the probe settings, the floor's offset, the inputs and the frame."""
    return {
        "particle_radius_m": cfg.particle_radius,
        "steps": cfg.steps,
        "dt": cfg.dt,
        "speed_m_s": cfg.speed,
        "directions": list(cfg.directions),
        "floor_lattice_offset": np.round(shift, 6).tolist(),
        "reference": str(reference.path),
        "reconstruction": str(recon.path),
        "up": list(reference.transform.up),
        "scale_m_per_unit": reference.transform.scale,
    }


class _Runs:
    """The probe runs of a comparison on one progress ``bar`` (a cached run moves it by its ``steps`` at once)."""

    def __init__(self, bar, steps: int):
        self.bar, self.steps, self.done, self.hits, self.seconds = bar, steps, 0, 0, 0.0

    def run(self, solid, setup, cfg, grid, label: str) -> FlowRecord:
        self.bar.set_description(label)
        t0 = time.perf_counter()
        rec = run_flow(solid, setup, cfg, grid, progress=lambda _st: self.bar.update(1))
        self.seconds += time.perf_counter() - t0
        self.done += 1
        return rec

    def cached(self, cache: FlowCache, solid, setup, cfg, grid, label: str) -> FlowRecord:
        key = cache.key(solid, setup, cfg, grid)
        rec = cache.get(key, cfg.steps, len(grid.points))
        if rec is not None:
            self.hits += 1
            self.bar.update(self.steps)
            return rec
        rec = self.run(solid, setup, cfg, grid, label)
        cache.put(key, rec)
        return rec


def comparison_lines(c: Comparison) -> list[str]:
    """The printed table: every figure beside its floor, per probe and in all, then the overlap."""

    def row(name: str, errs: dict, floor: dict) -> str:
        cells = "  ".join(f"{_pct(errs[m])} ({_pct(floor[m])})" for m in METRICS)
        return f"  {name:<6} {cells}"

    head = "  probe  " + "  ".join(f"{m} (floor)" for m in METRICS)
    lines = ["functional error against the reference (relative; floor: the reference on a shifted lattice):", head]
    lines += [row(d, c.probes[d], c.floors[d]) for d in c.probes]
    if len(c.probes) > 1:
        lines.append(row("all", c.overall, c.overall_floor))
    for d, p in c.probes.items():
        lines.append(
            f"  probe {d}: time-mean drag {p['drag_N']:.3g} N (reference {p['reference_drag_N']:.3g}), lift "
            f"{p['lift_N']:.3g} N (reference {p['reference_lift_N']:.3g})"
        )
    return [*lines, verdict_line(c.error, c.floor)]


def verdict_line(error: float, floor: float) -> str:
    """The headline error against its floor; no verdict where the floor itself is FLOOR_LIMIT or more."""
    head = f"functional error ({HEADLINE}): {_pct(error)}"
    if not floor < FLOOR_LIMIT:
        return (
            f"{head}, but its noise floor is {_pct(floor)}: the reference on a shifted lattice already differs this "
            "much, so this run cannot judge the reconstruction; raise --steps (the fluid must pass the object: the "
            "time mean is over the second half of the steps) or lower --particle-radius"
        )
    if error > 2.0 * floor:
        return f"{head}, above its noise floor {_pct(floor)}"
    return (
        f"{head}, within twice its noise floor {_pct(floor)}: this reconstruction's flow is indistinguishable from the "
        "reference's"
    )


def _pct(v: float) -> str:
    if not np.isfinite(v):
        return "inf"
    return f"{100 * v:.0f} %" if abs(v) >= 0.1 else f"{100 * v:.2g} %"


def overlap_line(overlap: Overlap, floor: Overlap) -> str:
    return (
        f"solids: occupancy IoU {overlap.iou:.3f} (floor {floor.iou:.3f}), Chamfer {overlap.chamfer * 1000:.3g} mm "
        f"(floor {floor.chamfer * 1000:.3g} mm)"
    )


def plot_forces(c: Comparison, path: Path) -> Path:
    """A PNG of each probe's drag over time: the reference, its shifted copy (the floor) and the reconstruction,
    each as its moving mean; written atomically."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    from fluidsim.files import atomic_output  # noqa: PLC0415

    fig, axes = plt.subplots(len(c.flows), 1, figsize=(7, 2.6 * len(c.flows)), squeeze=False)
    for ax, (d, flows) in zip(axes[:, 0], c.flows.items(), strict=True):
        for key, style in (("reference", "k-"), ("shifted", "0.6"), ("reconstruction", "C3-")):
            rec = flows[key]
            t, drag = np.cumsum(rec.dt), moving_mean(rec.forces, rec.dt) @ flow_axis(d)
            label = "reference, shifted" if key == "shifted" else key
            ax.plot(t[len(t) - len(drag) :], drag, style, lw=1.2, label=label)
        ax.set_title(f"probe {d}: drag ({FORCE_WINDOW_S:g} s moving mean)", fontsize=9)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("N")
        ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return Path(path)


class FunctionalTarget:
    """The functional error of many reconstructions of one object (the oracle's candidates, an evaluation's runs):
    the object's solid, frame and flows made once, then one probe run per reconstruction and direction.

    Args:
        reference: the object's :class:`~nbv.functional.solids.SolidSource` (its frame is used for every
            reconstruction). config: probe settings; ``directions`` the probes. cache: the object's flows (None: kept
            in memory only, for this object).

    Example:
        >>> target = FunctionalTarget(reference_source(Path("mesh.ply"), cfg, None, None), cfg)  # doctest: +SKIP
        >>> target.error(gaussians).error  # the headline, relative                             # doctest: +SKIP
    """

    def __init__(self, reference: SolidSource, config: PhysicsConfig, cache: FlowCache | None = None):
        self.reference, self.config = reference, config
        self.cache = cache if cache is not None else _MemoryCache()

    def error(self, gaussians, label: str = "reconstruction") -> Comparison:
        """The :class:`Comparison` of ``gaussians`` (a GaussianSet in the object's scene frame) with the object."""
        from nbv.functional.solids import reconstruction_source  # noqa: PLC0415

        recon = reconstruction_source(Path(label), self.config, self.reference.transform, lambda _p: gaussians)
        return compare(self.reference, recon, self.config, self.config.directions, progress=False, cache=self.cache)


class _MemoryCache(FlowCache):
    """A :class:`FlowCache` in memory, for the life of one :class:`FunctionalTarget` (no disk)."""

    def __init__(self):
        super().__init__(None)
        self._flows: dict[str, FlowRecord] = {}

    def get(self, key: str, steps: int, points: int) -> FlowRecord | None:
        return self._flows.get(key)

    def put(self, key: str, rec: FlowRecord) -> None:
        self._flows[key] = rec
