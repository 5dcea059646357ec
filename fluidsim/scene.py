"""Scene files: a JSON description of one simulation, validated once into frozen dataclasses.

Keys (unknown keys and bad values are errors that name the key)::

    {
      "particle_radius": 0.025,          # m
      "rest_density": 1000.0,            # kg/m^3
      "viscosity": 10.0,                 # dynamic, Pa s
      "gravity": [0, -9.81, 0],          # m/s^2, Y-up
      "dt": 0.002,                       # s (initial dt in CFL mode)
      "steps": 750,
      "domain": {"min": [..], "max": [..], "walls": true, "wall_layers": 2},
      "fluid_blocks": [{"min": [..], "max": [..], "velocity": [..]}],
      "solids": [{"points": "solid.npy"} | {"mesh": "car.obj", "fill": true}],
      "solver": {...}                    # optional: any SolverConfig field but the ones above
    }

Paths in ``solids`` are relative to the scene file.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from fluidsim.files import input_problem, read_json

from .config import MAX_STEPS, SolverConfig

MAX_FLUID_BLOCKS = 1000  # boxes of fluid in a scene (checked pairwise for overlaps)

TOP_KEYS = {
    "particle_radius",
    "rest_density",
    "viscosity",
    "gravity",
    "dt",
    "steps",
    "domain",
    "fluid_blocks",
    "solids",
    "solver",
}
REQUIRED_TOP = TOP_KEYS - {"solver", "solids", "gravity"}
SOLVER_KEYS = set(SolverConfig.field_names()) - {"particle_radius", "rest_density", "viscosity", "gravity", "dt"}


class SceneError(ValueError):
    """A scene file or dictionary is invalid; the message names the key and the fix."""


@dataclass(frozen=True)
class Domain:
    """Axis-aligned simulation box, m. Fluid leaving it is retired; ``walls`` closes it with particles."""

    min: tuple[float, float, float]
    max: tuple[float, float, float]
    walls: bool = True
    wall_layers: int = 2


@dataclass(frozen=True)
class FluidBlock:
    """A box of fluid on the particle lattice, m, with a uniform initial velocity, m/s."""

    min: tuple[float, float, float]
    max: tuple[float, float, float]
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Solid:
    """A static solid: a point set (``.npy`` N x 3 or ``.ply``) or a triangle mesh (surface or filled)."""

    points: str | None = None
    mesh: str | None = None
    fill: bool = True


@dataclass(frozen=True)
class Scene:
    """A validated scene. ``config`` holds every solver parameter; ``base_dir`` resolves solid paths."""

    config: SolverConfig
    steps: int
    domain: Domain
    fluid_blocks: tuple[FluidBlock, ...]
    solids: tuple[Solid, ...]
    base_dir: str = "."

    def to_dict(self) -> dict[str, Any]:
        """The scene as JSON-ready data (the same keys a scene file uses)."""
        cfg = asdict(self.config)
        top = {k: cfg.pop(k) for k in ("particle_radius", "rest_density", "viscosity", "gravity", "dt")}
        top["gravity"] = list(top["gravity"])
        return {
            **top,
            "steps": self.steps,
            "domain": {
                "min": list(self.domain.min),
                "max": list(self.domain.max),
                "walls": self.domain.walls,
                "wall_layers": self.domain.wall_layers,
            },
            "fluid_blocks": [
                {"min": list(b.min), "max": list(b.max), "velocity": list(b.velocity)} for b in self.fluid_blocks
            ],
            "solids": [({"points": s.points} if s.points else {"mesh": s.mesh, "fill": s.fill}) for s in self.solids],
            "solver": cfg,
        }

    def with_steps(self, steps: int) -> Scene:
        return replace(self, steps=_steps(steps))


def _steps(value: Any) -> int:
    steps = _int(value, "steps", 1)
    if steps > MAX_STEPS:
        raise SceneError(
            f"scene key 'steps' = {steps} is more than the {MAX_STEPS:,} time steps a run may have (the paper's "
            "probes run 750); run fewer steps"
        )
    return steps


def _num(value: Any, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SceneError(f"scene key '{key}' must be a finite number, got {value!r}")
    return float(value)


def _int(value: Any, key: str, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise SceneError(f"scene key '{key}' must be an integer >= {low}, got {value!r}")
    return value


def _vec(value: Any, key: str) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise SceneError(f"scene key '{key}' must be a list of 3 numbers [x, y, z], got {value!r}")
    return tuple(_num(v, f"{key}[{i}]") for i, v in enumerate(value))  # type: ignore[return-value]


def _keys(obj: Any, key: str, allowed: set[str], required: set[str]) -> dict:
    if not isinstance(obj, dict):
        raise SceneError(f"scene key '{key}' must be an object, got {type(obj).__name__}")
    unknown = sorted(set(obj) - allowed)
    if unknown:
        raise SceneError(f"unknown key(s) {unknown} in '{key}'; allowed keys: {sorted(allowed)}")
    missing = sorted(required - set(obj))
    if missing:
        raise SceneError(f"missing key(s) {missing} in '{key}'")
    return obj


def _box(obj: dict, key: str) -> tuple[tuple, tuple]:
    lo, hi = _vec(obj["min"], f"{key}.min"), _vec(obj["max"], f"{key}.max")
    if any(a >= b for a, b in zip(lo, hi, strict=True)):
        raise SceneError(f"scene key '{key}': min {list(lo)} must be below max {list(hi)} on every axis")
    return lo, hi


def _boxes_overlap(lo, hi, other_lo, other_hi) -> bool:
    """Whether two boxes share a volume (boxes that only touch do not)."""
    return all(a < d and c < b for a, b, c, d in zip(lo, hi, other_lo, other_hi, strict=True))


def _check_block_holds_fluid(key: str, lo: tuple, hi: tuple, spacing: float) -> None:
    """SceneError when a fluid block is thinner than the particle spacing on an axis: its lattice is empty."""
    counts = lattice_counts(lo, hi, spacing)
    if counts.min() >= 1:
        return
    axis = int(np.argmin(counts))
    size = hi[axis] - lo[axis]
    raise SceneError(
        f"scene key '{key}' box {list(lo)}..{list(hi)} is {size:.4g} m along {'xyz'[axis]}, less than "
        f"the particle spacing {spacing:.4g} m (2 x particle_radius), so it holds no fluid particle; "
        f"make it at least {spacing:.4g} m on every axis or use a smaller particle_radius"
    )


def parse_scene(data: dict, base_dir: str | Path = ".") -> Scene:
    """Validate a scene dictionary (see the module docstring) into a :class:`Scene`.

    Raises:
        SceneError: naming the offending key.
    """
    _keys(data, "scene", TOP_KEYS, REQUIRED_TOP)
    solver = _keys(data.get("solver", {}), "solver", SOLVER_KEYS, set())
    try:
        config = SolverConfig(
            particle_radius=_num(data["particle_radius"], "particle_radius"),
            rest_density=_num(data["rest_density"], "rest_density"),
            viscosity=_num(data["viscosity"], "viscosity"),
            gravity=_vec(data.get("gravity", [0.0, -9.81, 0.0]), "gravity"),
            dt=_num(data["dt"], "dt"),
            **{k: tuple(v) if isinstance(v, list) else v for k, v in solver.items()},
        )
    except SceneError:
        raise
    except (ValueError, TypeError) as exc:
        raise SceneError(f"invalid solver setting: {exc}") from exc
    steps = _steps(data["steps"])
    dom = _keys(data["domain"], "domain", {"min", "max", "walls", "wall_layers"}, {"min", "max"})
    dmin, dmax = _box(dom, "domain")
    walls = dom.get("walls", True)
    if not isinstance(walls, bool):
        raise SceneError(f"scene key 'domain.walls' must be true or false, got {walls!r}")
    domain = Domain(dmin, dmax, walls, _int(dom.get("wall_layers", 2), "domain.wall_layers", 1))
    blocks_raw = data["fluid_blocks"]
    if not isinstance(blocks_raw, list):
        raise SceneError("scene key 'fluid_blocks' must be a list of {min, max, velocity} objects")
    if len(blocks_raw) > MAX_FLUID_BLOCKS:
        raise SceneError(
            f"scene key 'fluid_blocks' lists {len(blocks_raw):,} blocks, more than the {MAX_FLUID_BLOCKS:,} a scene "
            "may have; merge them into fewer boxes"
        )
    blocks = []
    for i, b in enumerate(blocks_raw):
        key = f"fluid_blocks[{i}]"
        _keys(b, key, {"min", "max", "velocity"}, {"min", "max"})
        lo, hi = _box(b, key)
        # Overlapping blocks put particles on the same lattice points: the density doubles, and 10^5 copies of one
        # block gave every particle 10^5 neighbours, a first step of hours inside one kernel (no signal stops it).
        other = next((j for j, o in enumerate(blocks) if _boxes_overlap(lo, hi, o.min, o.max)), None)
        if other is not None:
            raise SceneError(f"scene key '{key}' overlaps 'fluid_blocks[{other}]'; fluid blocks must not overlap")
        vel = _vec(b.get("velocity", [0.0, 0.0, 0.0]), f"{key}.velocity")
        if any(l < a or h > c for l, h, a, c in zip(lo, hi, dmin, dmax, strict=True)):
            raise SceneError(
                f"scene key '{key}' box {list(lo)}..{list(hi)} must lie inside the domain {list(dmin)}..{list(dmax)}"
            )
        _check_block_holds_fluid(key, lo, hi, config.spacing)
        blocks.append(FluidBlock(lo, hi, vel))
    solids_raw = data.get("solids", [])
    if not isinstance(solids_raw, list):
        raise SceneError("scene key 'solids' must be a list of {points: PATH} or {mesh: PATH, fill: bool}")
    solids = []
    base = Path(base_dir)
    for i, s in enumerate(solids_raw):
        key = f"solids[{i}]"
        _keys(s, key, {"points", "mesh", "fill"}, set())
        if ("points" in s) == ("mesh" in s):
            raise SceneError(f"scene key '{key}' needs exactly one of 'points' or 'mesh'")
        path = s.get("points") or s.get("mesh")
        if not isinstance(path, str):
            raise SceneError(f"scene key '{key}': a file path is a string, got {path!r}")
        problem = input_problem(base / path)
        if problem == "does not exist":
            raise SceneError(f"scene key '{key}': file {path!r} not found (paths are relative to {base})")
        if problem is not None:  # a FIFO would block the reader and /dev/zero never ends
            raise SceneError(f"scene key '{key}': {path!r} {problem}")
        fill = s.get("fill", True)
        if not isinstance(fill, bool):
            raise SceneError(f"scene key '{key}.fill' must be true or false, got {fill!r}")
        if "points" in s and "fill" in s:
            raise SceneError(f"scene key '{key}.fill' applies to meshes only")
        solids.append(Solid(points=s.get("points"), mesh=s.get("mesh"), fill=fill))
    if not blocks:
        raise SceneError("scene key 'fluid_blocks' is empty: add at least one {min, max, velocity} block")
    return Scene(config, steps, domain, tuple(blocks), tuple(solids), str(base))


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene JSON file.

    Raises:
        SceneError: the file is missing, not JSON, or has a bad key (named in the message).
    """
    p = Path(path)
    try:
        data = read_json(p, "scene file", "a scene is a JSON object of a few levels (format in README.md)")
    except ValueError as exc:
        raise SceneError(str(exc)) from None
    try:
        return parse_scene(data, p.parent)
    except SceneError as exc:
        raise SceneError(f"{p}: {exc}") from exc


def lattice_in_box(box_min, box_max, spacing: float) -> np.ndarray:
    """Cell-centred lattice points ``min + (i + 1/2) spacing`` inside a box.

    Args:
        box_min, box_max: (3,) m. spacing: m.
    Returns:
        (K, 3) float64 points.
    """
    lo = np.asarray(box_min, np.float64)
    counts = lattice_counts(box_min, box_max, spacing).astype(int)
    axes = [lo[d] + (np.arange(counts[d]) + 0.5) * spacing for d in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def lattice_counts(box_min, box_max, spacing: float) -> np.ndarray:
    """Points per axis of :func:`lattice_in_box` (nothing is allocated; may be astronomically large).

    Args:
        box_min, box_max: (3,) m. spacing: m.
    Returns:
        (3,) float64 counts, ``floor((max - min) / spacing)`` (0 on an axis shorter than the spacing).
    """
    lo = np.asarray(box_min, np.float64)
    hi = np.asarray(box_max, np.float64)
    return np.maximum(np.floor((hi - lo) / spacing + 1e-9), 0.0)
