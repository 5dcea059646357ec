"""Reading a simulation file for :mod:`viz.frames`: the frame keys in order, the domain box (from the scene, or
fitted to the particles), the walls and the solid, and the colour scale's v_max, all checked before a frame is drawn.
An OUT.h5 of `fluidgs sim` gives its ``/frames``; a RESULT.h5 of `fluidgs simulate --record-probe` the recorded
trajectory of one probe (:class:`TrajectorySource`).
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import h5py
import numpy as np
from scipy.spatial import cKDTree

from .frame_style import COLOR_BY, FrameStyle

logger = logging.getLogger(__name__)

MAX_BOUNDARY_POINTS = 50_000  # walls drawn at most
MAX_SOLID_POINTS = 400_000
VMAX_PERCENTILE = 99.0
VMAX_MAX_SAMPLES = 2_000_000  # values pooled over all frames to estimate the percentile


class FrameSource:
    """A checked, open simulation file: frame keys in order, domain box and what to read per frame."""

    def __init__(self, file, path, keys, counts, value_name, domain, boundary, walls=None) -> None:
        self.file: h5py.File = file
        self.path: Path = path
        self.keys: tuple[str, ...] = keys
        self.counts: tuple[int, ...] = counts
        self.value_name: str = value_name
        self.domain_min, self.domain_max = domain
        self.boundary: np.ndarray | None = boundary  # (M', 3) finite solid particles, already subsampled
        self.walls: np.ndarray | None = walls  # (W', 3) finite wall particles, already subsampled
        self.dropped = 0  # particles skipped so far because their position was NaN or inf

    @staticmethod
    def inspect(f: h5py.File, path: Path, style: FrameStyle, probe: str | None = None) -> FrameSource:
        """The frames of an OUT.h5 (``/frames``), or of a probe's recorded trajectory in a RESULT.h5
        (:class:`TrajectorySource`; ``probe``: which, default the first recorded)."""
        frames = f.get("/frames")
        if not isinstance(frames, h5py.Group) and isinstance(f.get("/probes"), h5py.Group):
            return TrajectorySource.inspect_result(f, path, style, probe)
        if probe is not None:
            raise ValueError(f"{path} is a simulation output file (OUT.h5): --probe {probe} is for a RESULT.h5")
        if not isinstance(frames, h5py.Group):
            raise ValueError(f"{path} has no /frames group; is it a simulation output file (OUT.h5)?")
        bad = [k for k in frames if not k.isdigit()]
        if bad:
            raise ValueError(f"{path}: /frames holds non-numeric keys {bad[:5]}; expected e.g. '000010'")
        keys = tuple(sorted(frames, key=int))
        if not keys:
            raise ValueError(f"{path}: /frames is empty; run the simulation long enough to write a frame")
        value_name = COLOR_BY[style.color_by][0]
        counts = []
        for k in keys:
            g = frames[k]
            where = f"{path}:/frames/{k}"
            if not isinstance(g, h5py.Group):
                raise ValueError(f"{where} is not a group")
            x = _dataset(g, "x", where)
            val = _dataset(g, value_name, where, hint=f"or choose another --color-by than {style.color_by}")
            if x.ndim != 2 or x.shape[1] != 3:
                raise ValueError(f"{where}/x must have shape (N, 3), got {x.shape}")
            n = x.shape[0]
            want = (n, 3) if value_name == "v" else (n,)
            if val.shape != want:
                raise ValueError(
                    f"{where}/{value_name} has shape {val.shape}; x has shape {x.shape}, so expected {want}"
                )
            for attr in ("time", "step"):
                if attr not in g.attrs:
                    raise ValueError(f"{where} lacks the attribute '{attr}'")
            counts.append(n)

        boundary = walls = None
        domain = _domain_from_scene(f, path)
        if style.show_boundary and "boundary" in f and "x" in f["boundary"]:
            boundary, walls = _read_boundary(f["boundary"]["x"], path, domain)
        if domain is None:
            domain = _domain_from_particles(frames, keys, boundary)
        return FrameSource(f, path, keys, tuple(counts), value_name, domain, boundary, walls)

    def frame(self, i: int) -> tuple[np.ndarray, np.ndarray, float, int]:
        """Positions (N', 3) with non-finite rows dropped, their colour values (N',), time [s], step."""
        g = self.file["frames"][self.keys[i]]
        x = np.asarray(g["x"][()], dtype=np.float64)
        values = _magnitudes(g[self.value_name][()])
        ok = np.isfinite(x).all(axis=1)
        if not ok.all():
            self.dropped += int((~ok).sum())
            x, values = x[ok], values[ok]
        return x, values, float(g.attrs["time"]), int(g.attrs["step"])

    def spacing(self, solid: np.ndarray) -> float | None:
        """The particle spacing [m]: 2 x the scene's ``particle_radius``, else the median nearest-neighbour distance
        of (at most 5,000 of) the solid particles, else None."""
        raw = self.file.attrs.get("scene")
        try:
            radius = json.loads(raw.decode() if isinstance(raw, bytes) else str(raw)).get("particle_radius")
            if radius is not None and float(radius) > 0:
                return 2.0 * float(radius)
        except (ValueError, TypeError, AttributeError):
            pass
        if len(solid) < 2:
            return None
        sample = solid[:: max(1, len(solid) // 5000)]
        dist, _ = cKDTree(solid).query(sample, k=2)
        return float(np.median(dist[:, 1])) or None

    def percentile_vmax(self) -> float:
        """99th percentile of the colour values over all frames (strided sample of at most 2M values)."""
        stride = max(1, math.ceil(sum(self.counts) / VMAX_MAX_SAMPLES))
        pooled = [_magnitudes(self.file["frames"][k][self.value_name][()])[::stride] for k in self.keys]
        values = np.concatenate(pooled) if pooled else np.zeros(0)
        values = values[np.isfinite(values)]
        vmax = float(np.percentile(values, VMAX_PERCENTILE)) if values.size else 0.0
        if not vmax > 0:
            vmax = float(values.max()) if values.size else 0.0
        if not vmax > 0:
            logger.warning("%s: all %s values are zero; using vmax = 1", self.path, self.value_name)
            vmax = 1.0
        return vmax


# color_by -> the dataset of a RESULT.h5 trajectory (nbv.physics.trajectory: D and speed per recorded step)
TRAJECTORY_VALUES = {"divergence": "D", "speed": "speed"}


class TrajectorySource(FrameSource):
    """The recorded fluid of one probe of a RESULT.h5 (``fluidgs simulate --record-probe``): the frames are the
    recorded steps of ``/probes/<dir>/trajectory`` (x (T, F, 3), D and speed (T, F); NaN rows: retired), the box is
    the probe's domain, the solid is ``/solid/x``, the time is step x the run's dt."""

    def __init__(self, file, path, keys, counts, value_name, domain, boundary, group, dt, spacing) -> None:
        super().__init__(file, path, keys, counts, value_name, domain, boundary)
        self.group, self.dt, self._spacing = group, dt, spacing

    @staticmethod
    def inspect_result(f: h5py.File, path: Path, style: FrameStyle, probe: str | None) -> TrajectorySource:
        probes = f["probes"]
        recorded = [d for d in probes if isinstance(probes[d], h5py.Group) and "trajectory" in probes[d]]
        if not recorded:
            raise ValueError(
                f"{path} is a RESULT.h5 without a recorded probe; re-run `fluidgs simulate` (or score --save-result) "
                "with --record-probe -x"
            )
        chosen = recorded[0] if probe is None else probe
        if chosen not in recorded:
            raise ValueError(f"{path} has no trajectory of probe {chosen} (recorded: {', '.join(recorded)})")
        if probe is None and len(recorded) > 1:
            logger.info("%s: probe %s (recorded: %s; --probe picks another)", path, chosen, ", ".join(recorded))
        group = probes[chosen]["trajectory"]
        where = f"{path}:/probes/{chosen}/trajectory"
        name = TRAJECTORY_VALUES[style.color_by]
        x, values = _dataset(group, "x", where), _dataset(group, name, where)
        steps = np.asarray(_dataset(group, "steps", where)[()], np.int64)
        if x.ndim != 3 or x.shape[2] != 3 or values.shape != x.shape[:2] or len(steps) != x.shape[0]:
            raise ValueError(f"{where}: x {x.shape}, {name} {values.shape} and steps {steps.shape} do not match")
        if not len(steps):
            raise ValueError(f"{where} holds no frame; record with a smaller --record-every")
        pg = probes[chosen]
        if "domain_min" in pg.attrs and "domain_max" in pg.attrs:
            domain = (np.asarray(pg.attrs["domain_min"], np.float64), np.asarray(pg.attrs["domain_max"], np.float64))
        else:
            domain = None
        config = json.loads(str(f.attrs.get("config", "{}")))
        solid = None
        if style.show_boundary and "solid" in f and "x" in f["solid"]:
            solid = np.asarray(f["solid"]["x"][()], np.float64).reshape(-1, 3)
            solid = _subset(solid[np.isfinite(solid).all(axis=1)], MAX_SOLID_POINTS, path, "solid")
        source = TrajectorySource(
            f,
            path,
            tuple(str(int(s)) for s in steps),
            tuple([int(x.shape[1])] * len(steps)),
            name,
            domain if domain is not None else (np.zeros(3), np.ones(3)),
            solid,
            group,
            float(config.get("dt", 0.002)),
            2.0 * float(config.get("particle_radius", 0.025)),
        )
        if domain is None:
            lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
            for i in range(len(steps)):
                pts, _, _, _ = source.frame(i)
                if len(pts):
                    lo, hi = np.minimum(lo, pts.min(0)), np.maximum(hi, pts.max(0))
            source.domain_min, source.domain_max = (lo, hi) if np.isfinite(lo).all() else (np.zeros(3), np.ones(3))
            source.dropped = 0
        return source

    def frame(self, i: int) -> tuple[np.ndarray, np.ndarray, float, int]:
        x = np.asarray(self.group["x"][i], np.float64)
        values = _magnitudes(self.group[self.value_name][i])
        ok = np.isfinite(x).all(axis=1)  # NaN rows: particles retired before this step
        step = int(self.keys[i])
        return x[ok], values[ok], step * self.dt, step

    def spacing(self, solid: np.ndarray) -> float | None:
        return self._spacing

    def percentile_vmax(self) -> float:
        values = np.asarray(self.group[self.value_name][()], np.float64).reshape(-1)
        values = np.abs(values[np.isfinite(values)])
        stride = max(1, math.ceil(values.size / VMAX_MAX_SAMPLES))
        values = values[::stride]
        vmax = float(np.percentile(values, VMAX_PERCENTILE)) if values.size else 0.0
        return vmax if vmax > 0 else 1.0


def check_frames_file(path: Path) -> None:
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist; pass the OUT.h5 written by the simulation or a RESULT.h5")
    if not path.is_file():
        raise ValueError(f"{path} is not a file; pass the OUT.h5 written by the simulation or a RESULT.h5")
    if not h5py.is_hdf5(path):
        raise ValueError(f"{path} is not an HDF5 file; pass the OUT.h5 written by the simulation or a RESULT.h5")
    try:  # an HDF5 signature on a truncated or damaged file: h5py says so only when it opens it
        h5py.File(path, "r").close()
    except (OSError, RuntimeError) as exc:
        raise ValueError(
            f"{path} is a truncated or damaged HDF5 file ({exc}); pass a complete OUT.h5 or RESULT.h5, "
            "or write it again"
        ) from None


def _dataset(group: h5py.Group, name: str, where: str, hint: str = "") -> h5py.Dataset:
    ds = group.get(name)
    if not isinstance(ds, h5py.Dataset):
        raise ValueError(f"{where} has no dataset '{name}'" + (f"; {hint}" if hint else ""))
    if ds.dtype.kind not in "fiu":
        raise ValueError(f"{where}/{name} has dtype {ds.dtype}; expected a float array")
    return ds


def _magnitudes(values: np.ndarray) -> np.ndarray:
    """Colour value per particle: |value| for (N,), Euclidean norm for (N, 3)."""
    values = np.asarray(values, dtype=np.float64)
    return np.linalg.norm(values, axis=1) if values.ndim == 2 else np.abs(values)


def _read_boundary(ds: h5py.Dataset, path: Path, domain) -> tuple[np.ndarray, np.ndarray]:
    """(solid, walls): the boundary particles inside and outside the domain box (all solid without a domain), each
    a uniform random subset (fixed seed) of at most MAX_SOLID_POINTS / MAX_BOUNDARY_POINTS when larger.

    Random rather than strided, because a stride through a regularly sampled wall draws moire patterns.
    The dataset is read in blocks so that a huge boundary never sits in memory whole.
    """
    if ds.ndim != 2 or ds.shape[1] != 3 or ds.dtype.kind not in "fiu":
        raise ValueError(f"{path}:/boundary/x must be a float array of shape (M, 3), got {ds.shape} {ds.dtype}")
    block = 1 << 20
    solid, walls = [], []
    for start in range(0, ds.shape[0], block):
        points = np.asarray(ds[start : start + block], dtype=np.float64).reshape(-1, 3)
        points = points[np.isfinite(points).all(axis=1)]
        inside = (
            np.ones(len(points), bool)
            if domain is None
            else ((points >= domain[0]) & (points <= domain[1])).all(axis=1)
        )
        solid.append(points[inside])
        walls.append(points[~inside])
    return (
        _subset(np.concatenate(solid or [np.zeros((0, 3))]), MAX_SOLID_POINTS, path, "solid"),
        _subset(np.concatenate(walls or [np.zeros((0, 3))]), MAX_BOUNDARY_POINTS, path, "wall"),
    )


def _subset(points: np.ndarray, limit: int, path: Path, what: str) -> np.ndarray:
    if len(points) <= limit:
        return points
    chosen = np.sort(np.random.default_rng(0).choice(len(points), limit, replace=False))
    logger.info("%s: drawing %d of %d %s particles", path, limit, len(points), what)
    return points[chosen]


def _domain_from_scene(f: h5py.File, path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """Domain box from the root ``scene`` JSON, or None (with a warning) when it is missing or unusable."""
    raw = f.attrs.get("scene")
    try:
        if raw is None:
            raise ValueError("the root attribute 'scene' is missing")
        if isinstance(raw, bytes):
            raw = raw.decode("utf-8")
        domain = json.loads(str(raw))["domain"]
        return check_domain(domain["min"], domain["max"])
    except (ValueError, KeyError, TypeError) as e:
        logger.warning("%s: no usable scene domain (%s); fitting the view to the particles instead", path, e)
        return None


def _domain_from_particles(frames: h5py.Group, keys, boundary) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    clouds = [frames[k]["x"][()] for k in keys] + ([boundary] if boundary is not None else [])
    for points in clouds:
        points = np.asarray(points, dtype=np.float64)
        points = points[np.isfinite(points).all(axis=1)]
        if len(points):
            lo, hi = np.minimum(lo, points.min(axis=0)), np.maximum(hi, points.max(axis=0))
    if not np.isfinite(lo).all():
        lo, hi = np.zeros(3), np.ones(3)
    pad = 0.5 * max(float((hi - lo).max()), 1e-3)
    flat = hi - lo < 1e-9
    return np.where(flat, lo - pad, lo), np.where(flat, hi + pad, hi)


def check_domain(domain_min, domain_max) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(domain_min, dtype=np.float64)
    hi = np.asarray(domain_max, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,):
        raise ValueError(f"domain min and max must have shape (3,), got {lo.shape} and {hi.shape}")
    if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (lo < hi).all()):
        raise ValueError(f"domain needs finite min < max on every axis, got min {lo} and max {hi}")
    return lo, hi


def box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(8, 3) corners; bit i of the corner index selects max along axis i."""
    return np.array([[hi[a] if (c >> a) & 1 else lo[a] for a in range(3)] for c in range(8)])
