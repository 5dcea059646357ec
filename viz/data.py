"""What the viewer reads from RESULT.h5, with h5py and numpy only (no Taichi, no torch).

The layout is the one :func:`nbv.physics.save_result` writes (and :mod:`nbv.physics.trajectory` for the recorded
probes); this module reads the part the viewer shows, and names what is missing and the command that makes it when a
file comes from another version. ``nbv`` itself is not imported: it loads Taichi, which the viewer never needs.

Everything is in the simulation frame: metres, Y-up. ``scene_to_sim`` (4 x 4, x_sim = M [x_scene, 1]) maps the
Gaussians' and the cameras' scene coordinates to it; files written before it was stored have ``up_axis``
("y" or "z") and ``scale`` instead, from which the same matrix is built.
"""

from __future__ import annotations

import json
import logging
import math
import shlex
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from fluidsim.directions import DIRECTIONS  # the names only: no Taichi (fluidsim's package init is lazy)
from fluidsim.files import check_input_file

log = logging.getLogger(__name__)

# simulate's defaults: only settings that differ from them are written into a suggested command
_DEFAULTS = {
    "particle_radius": 0.025,
    "steps": 750,
    "dt": 0.002,
    "speed": 3.0,
    "viscosity": 10.0,
    "accumulate_every": 1,
    "opacity_threshold": 0.3,
    "up": "+y",
    "scale": "auto",
}
# frames a suggested --record-every aims at (750 steps -> every 10)
TARGET_FRAMES = 75
REQUIRED = ("gaussians/D", "gaussians/D_mean", "gaussians/means", "gaussians/covariances", "solid/x")


@dataclass(frozen=True)
class LeakSummary:
    """One probe's leak measure (``/probes/<dir>/leaked``, :mod:`nbv.physics.leaks`).

    Attributes:
        final: fluid particles inside the filled solid at the end. max: the most after any step; max_step: when.
        x_leaked: [K, 3] float32 their final positions, sim metres (empty when the file has no final positions).
    """

    final: int
    max: int
    max_step: int
    x_leaked: np.ndarray


@dataclass(frozen=True)
class Trajectory:
    """One recorded probe (``/probes/<dir>/trajectory``, :mod:`nbv.physics.trajectory`).

    Attributes:
        direction: the probe.
        steps: [T] steps completed at each frame; times = steps * dt (s).
        x: [T, F, 3] float32 positions, sim metres (NaN: retired).
        divergence: [T, F] float16 D_i, 1/s. speed: [T, F] float16 |v_i|, m/s (NaN: retired).
        dt: s per step.
    """

    direction: str
    steps: np.ndarray
    x: np.ndarray
    divergence: np.ndarray
    speed: np.ndarray
    dt: float

    @property
    def num_frames(self) -> int:
        return int(self.x.shape[0])

    def frame(self, index: int, values: str = "divergence") -> tuple[np.ndarray, np.ndarray]:
        """The active particles of frame ``index``: ([K, 3] float32 positions, [K] float32 D_i or speed)."""
        if not 0 <= index < self.num_frames:
            raise ValueError(
                f"frame {index} out of range: the trajectory of probe {self.direction} has {self.num_frames} frames"
            )
        x = self.x[index]
        v = np.asarray(getattr(self, values)[index], np.float32)
        active = np.isfinite(x).all(axis=1)
        return x[active], np.nan_to_num(v[active], nan=0.0, posinf=np.finfo(np.float32).max)


@dataclass(frozen=True)
class ViewData:
    """The part of RESULT.h5 the viewer shows.

    Attributes:
        path: the file. source: the Gaussian file it was computed from (its absolute path; as given to simulate
            in files written before). source_relative: the same relative to RESULT.h5's folder ("" when unknown).
        directions: the probes (P). per_probe: per direction, [G] D_g^(IC), 1/s.
        divergence, divergence_mean: [G] D_g max and mean over the probes, 1/s.
        means: [G, 3] sim metres. covariances: [G, 3, 3] sim metres^2. kept: [G] bool inside the crop, or None.
        solid: [M, 3] solid particles, sim metres. particle_radius: r, m. dt: s. steps: per probe.
        scene_to_sim: [4, 4]. dbar: D-bar, m^4/s. config: the PhysicsConfig as a dict.
        leaks: per direction with a leak measure. recorded: the directions with a trajectory.
        reached: per direction, the Gaussians its fluid reached (a sample within n r_g), of num_gaussians.
        dbar_empty: D-bar of the empty scene (no solid), m^4/s; NaN when it was not run.
        empty_per_probe: per direction, [G] the empty scene's D_g^(IC), 1/s (only with the empty reference).
        reached_gaussians: [G] bool, the Gaussians some probe's fluid reached (the others' D_g = 0 is unmeasured:
            drawn grey); None in a file without per-probe counts.
    """

    path: Path
    source: str
    directions: tuple[str, ...]
    per_probe: dict[str, np.ndarray]
    divergence: np.ndarray
    divergence_mean: np.ndarray
    means: np.ndarray
    covariances: np.ndarray
    kept: np.ndarray | None
    solid: np.ndarray
    particle_radius: float
    dt: float
    steps: int
    scene_to_sim: np.ndarray
    dbar: float
    config: dict
    leaks: dict[str, LeakSummary]
    recorded: tuple[str, ...]
    reached: dict[str, int] = field(default_factory=dict)
    dbar_empty: float = math.nan
    empty_per_probe: dict[str, np.ndarray] = field(default_factory=dict)
    reached_gaussians: np.ndarray | None = None
    source_relative: str = ""

    @property
    def num_gaussians(self) -> int:
        return int(self.divergence.shape[0])

    def metric(self, name: str) -> np.ndarray:
        """[G] D_g: "max", "mean", or one probe's ("-x", ...), 1/s."""
        if name == "max":
            return self.divergence
        if name == "mean":
            return self.divergence_mean
        if name not in self.per_probe:
            raise ValueError(f"{self.path} has no probe {name} (it has {', '.join(self.directions)})")
        return self.per_probe[name]

    def simulate_command(self, probe: str | None = None) -> str:
        """A `fluidgs simulate` command that writes this file again (with the settings of the first run that differ
        from the defaults), recording ``probe`` when given."""
        cfg = self.config
        args = ["fluidgs", "simulate", self.source or "GAUSSIANS.ply", "-o", str(self.path)]
        for key in _DEFAULTS:
            value = cfg.get(key, _DEFAULTS[key])
            if isinstance(value, list):
                value = ",".join(f"{c:g}" for c in value)
            if value != _DEFAULTS[key]:
                args.append(f"--{key.replace('_', '-')}={value}")
        dirs = tuple(cfg.get("directions", DIRECTIONS))
        if dirs != DIRECTIONS:
            args.append(f"--directions={','.join(dirs)}")
        args += [
            flag
            for key, flag in (("fill_cavities", "--no-fill"), ("empty_reference", "--no-empty-reference"))
            if cfg.get(key, True) is False
        ]
        if cfg.get("crop") is not None:
            crop = cfg["crop"]
            args.append(f"--crop={crop if isinstance(crop, str) else ','.join(f'{c:g}' for c in crop)}")
        if probe is not None:
            args += [f"--record-probe={probe}", "--record-every", str(max(1, round(self.steps / TARGET_FRAMES)))]
        return " ".join(shlex.quote(a) for a in args)


def _scene_to_sim(f: h5py.File, path: Path) -> np.ndarray:
    """[4, 4] from ``scene_to_sim``, else from the older ``up_axis`` + ``scale``."""
    if "scene_to_sim" in f.attrs:
        m = np.asarray(f.attrs["scene_to_sim"], np.float64)
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise ValueError(f"{path}: the attribute scene_to_sim must be a finite 4x4 matrix, got shape {m.shape}")
        return m
    if "scale" not in f.attrs or "up_axis" not in f.attrs:
        raise ValueError(
            f"{path} has neither the scene_to_sim attribute nor up_axis and scale, so its Gaussians and "
            "cameras cannot be placed; re-run `fluidgs simulate`"
        )
    up = str(f.attrs["up_axis"]).strip().lower().lstrip("+")
    rotations = {"y": np.eye(3), "z": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])}  # z-up: (x, y, z) -> (x, z, -y)
    if up not in rotations:
        raise ValueError(f"{path}: up_axis {up!r} is neither 'y' nor 'z'; re-run `fluidgs simulate`")
    m = np.eye(4)
    m[:3, :3] = float(f.attrs["scale"]) * rotations[up]
    return m


def _leaks(group: h5py.Group) -> LeakSummary | None:
    if "leaked" not in group:
        return None
    ds = group["leaked"]
    ids = np.asarray(ds[()], np.int64)
    x = np.zeros((0, 3), np.float32)
    if "x_final" in group and "ids_final" in group and len(ids):
        pos = np.searchsorted(group["ids_final"][()], ids)  # ids_final is sorted; leaked ids are among them
        x = np.asarray(group["x_final"][()], np.float32)[pos]
    return LeakSummary(
        final=int(ds.attrs.get("final", len(ids))),
        max=int(ds.attrs.get("max", len(ids))),
        max_step=int(ds.attrs.get("max_step", -1)),
        x_leaked=x,
    )


def _reached_gaussians(f: h5py.File, probes: dict[str, h5py.Group]) -> np.ndarray | None:
    """[G] bool /gaussians/reached, else (files written before it) some probe's counts > 0; None without counts."""
    if "gaussians/reached" in f:
        return f["gaussians/reached"][()].astype(bool)
    if probes and all("counts" in pg for pg in probes.values()):
        return np.sum([pg["counts"][()] for pg in probes.values()], axis=0) > 0
    return None


def load_view_data(path: str | Path) -> ViewData:
    """Read RESULT.h5 for the viewer (trajectories stay on disk: :func:`load_trajectory`).

    Raises:
        ValueError: the file is missing, not HDF5, not a `fluidgs simulate` result, or lacks an array or attribute
            the viewer needs (the message names it and the command that writes it).
    """
    p = Path(path)
    check_input_file(p, "RESULT.h5", f"write it with `fluidgs simulate GAUSSIANS.ply -o {p}`")
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        raise ValueError(f"{p} is not an HDF5 file ({exc}); pass the RESULT.h5 of `fluidgs simulate`") from None
    with f:
        from recon.inflate import check_hdf5_sizes  # noqa: PLC0415 - standard library and h5py only

        check_hdf5_sizes(f, str(p))
        source = str(f.attrs.get("source", ""))
        redo = f"re-run `fluidgs simulate {source or 'GAUSSIANS.ply'} -o {p}`"
        if "gaussians/D" not in f or "config" not in f.attrs or "directions" not in f.attrs:
            raise ValueError(f"{p} is not a `fluidgs simulate` result (no /gaussians/D or no config); {redo}")
        missing = [k for k in REQUIRED if k not in f]
        if missing:
            raise ValueError(
                f"{p} lacks {', '.join('/' + k for k in missing)} (written by another version of fluidgs); {redo}"
            )
        directions = tuple(json.loads(f.attrs["directions"]))
        if not directions:
            status = str(f.attrs.get("status", ""))
            why = (
                f"the run diverged in probe {f.attrs.get('diverged_probe')} at step {f.attrs.get('diverged_step')} "
                f"({f.attrs.get('diverged_reason')}) before completing any probe"
                if status == "diverged"
                else "it holds no probe"
            )
            raise ValueError(f"{p} has no D_g to show: {why}; {redo} with a smaller --dt or --speed")
        missing = [f"/probes/{d}/D" for d in directions if f"probes/{d}/D" not in f]
        if missing:
            raise ValueError(f"{p} lacks {', '.join(missing)}; {redo}")
        config = json.loads(f.attrs["config"])
        g = f["gaussians/D"].shape[0]
        means, covs = f["gaussians/means"][()], f["gaussians/covariances"][()]
        if means.shape != (g, 3) or covs.shape != (g, 3, 3):
            raise ValueError(
                f"{p}: /gaussians/means {means.shape} and /gaussians/covariances {covs.shape} do not "
                f"match the {g} Gaussians of /gaussians/D; {redo}"
            )
        probes = {d: f[f"probes/{d}"] for d in directions}
        return ViewData(
            path=p,
            source=source,
            directions=directions,
            per_probe={d: pg["D"][()] for d, pg in probes.items()},
            divergence=f["gaussians/D"][()],
            divergence_mean=f["gaussians/D_mean"][()],
            means=means,
            covariances=covs,
            kept=f["gaussians/kept"][()].astype(bool) if "gaussians/kept" in f else None,
            solid=np.asarray(f["solid/x"][()], np.float64).reshape(-1, 3),
            particle_radius=float(config.get("particle_radius", 0.025)),
            dt=float(config.get("dt", 0.002)),
            steps=int(config.get("steps", 0)),
            scene_to_sim=_scene_to_sim(f, p),
            dbar=float(f.attrs.get("dbar", math.nan)),
            config=config,
            leaks={d: lk for d, pg in probes.items() if (lk := _leaks(pg)) is not None},
            recorded=tuple(d for d, pg in probes.items() if "trajectory" in pg),
            reached={d: int((pg["counts"][()] > 0).sum()) for d, pg in probes.items() if "counts" in pg},
            dbar_empty=float(f.attrs.get("dbar_empty", math.nan)),
            empty_per_probe={d: pg["D_empty"][()] for d, pg in probes.items() if "D_empty" in pg},
            reached_gaussians=_reached_gaussians(f, probes),
            source_relative=str(f.attrs.get("source_relative", "")),
        )


def no_trajectory_message(data: ViewData, probe: str) -> str:
    """What to run when ``probe`` has no recorded trajectory."""
    others = f" (recorded: {', '.join(data.recorded)})" if data.recorded else ""
    return (
        f"{data.path.name} has no trajectory for probe {probe}{others}; re-run `{data.simulate_command(probe)}` "
        "to replay its fluid"
    )


def load_trajectory(data: ViewData, probe: str) -> Trajectory:
    """The recorded fluid of ``probe``.

    Raises:
        ValueError: ``probe`` is not a probe of the file, or was not recorded (the message says how to record it).
    """
    if probe not in data.directions:
        raise ValueError(f"--probe {probe}: {data.path} has the probes {', '.join(data.directions)}")
    if probe not in data.recorded:
        raise ValueError(no_trajectory_message(data, probe))
    with h5py.File(data.path, "r") as f:
        g = f[f"probes/{probe}/trajectory"]
        missing = [k for k in ("x", "D", "speed", "steps") if k not in g]
        if missing:
            raise ValueError(
                f"{data.path}: /probes/{probe}/trajectory lacks {', '.join(missing)}; "
                f"re-run `{data.simulate_command(probe)}`"
            )
        x, d, s, steps = g["x"][()], g["D"][()], g["speed"][()], np.asarray(g["steps"][()], np.int64)
    t = len(steps)
    if x.ndim != 3 or x.shape[0] != t or x.shape[2] != 3 or d.shape != x.shape[:2] or s.shape != x.shape[:2]:
        raise ValueError(
            f"{data.path}: /probes/{probe}/trajectory has inconsistent shapes (x {x.shape}, D {d.shape}, "
            f"speed {s.shape}, steps {steps.shape}); re-run `{data.simulate_command(probe)}`"
        )
    return Trajectory(direction=probe, steps=steps, x=np.asarray(x, np.float32), divergence=d, speed=s, dt=data.dt)
