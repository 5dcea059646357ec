"""How much memory a scene's solver needs, estimated from the scene alone before anything is allocated.

No paper equation: the particle counts follow from the scene's geometry (the fluid lattice of each block, the
wall lattice of :func:`fluidsim.sources.wall_particles`, the solids' files, the solver's grid over the domain)
and are multiplied by bytes per particle and per grid cell measured with ``fluidgs sim`` (peak resident memory
of one-step runs on the CPU, f32, r = 0.05 m), doubled for headroom:

============================  ==========  ====================================================================
item                          measured    what it holds
============================  ==========  ====================================================================
fluid particle                ~490 B      state, pressure-solver arrays, fluid and boundary neighbour lists
boundary particle             ~78 B       positions, volumes, the sort by cell (walls and solids)
grid cell                     ~17 B       cell counts and starts of the fluid and the boundary
============================  ==========  ====================================================================

A mesh solid also needs, while it is sampled, its surface candidates (3 per surface particle) and, when filled,
the lattice over its bounding box (:func:`fluidsim.sources.mesh_particles`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .config import RETIRE_MARGIN_MAX
from .grid import Z_SPLIT
from .host import available_memory_bytes
from .scene import Domain, Scene, SceneError, lattice_counts
from .sources import load_mesh, wall_particle_count

# measured peaks, plus the arrays of the force on the solid (fluidsim.forces): three vec3 per fluid particle at f64
# at most (the solid's gradient sum and the two viscous accelerations) and the i32 solid flag per boundary particle
BYTES_PER_FLUID = 1024 + 72
BYTES_PER_BOUNDARY = 160 + 4
BYTES_PER_CELL = 40
# sources.mesh_particles: per surface particle 3 candidates (indices, barycentrics, float64 positions, gathered
# corners); per point of a filled mesh's bounding-box lattice, float64 positions and the occupancy query
BYTES_PER_SURFACE_PARTICLE = 512
BYTES_PER_FILL_POINT = 96
# one slot of a particle's fluid and boundary neighbour lists (fluidsim.particles.Neighborhoods): f32 runs a 4-byte
# fluid pair and an 8-byte boundary pair, f64 runs 16 bytes each
BYTES_PER_LIST_SLOT = {"f32": 12, "f64": 32}


@dataclass(frozen=True)
class SceneMemory:
    """The estimate of :func:`estimate_scene_memory`. Counts are floats (they may exceed any int64).

    Attributes:
        fluid_particles: lattice points of all fluid blocks.
        wall_particles: the domain walls (0 without walls).
        solid_particles: every solid's particles (an upper estimate for meshes).
        grid_cells: cells of the solver's neighbour grid over the padded domain.
        sampling_bytes: the transient arrays of sampling the mesh solids, bytes.
        bytes: the total, bytes.
        list_bytes: the neighbour-list slots the scene's ``max_neighbors`` asks for beyond those of the default
            capacity (which ``BYTES_PER_FLUID`` holds), bytes.
    """

    fluid_particles: float
    wall_particles: float
    solid_particles: float
    grid_cells: float
    sampling_bytes: float
    bytes: float
    list_bytes: float = 0.0

    def parts(self) -> dict[str, float]:
        """Bytes per item: fluid, walls, solids (with their sampling) and grid."""
        return {
            "fluid": self.fluid_particles * BYTES_PER_FLUID,
            "walls": self.wall_particles * BYTES_PER_BOUNDARY,
            "solids": self.solid_particles * BYTES_PER_BOUNDARY + self.sampling_bytes,
            "grid": self.grid_cells * BYTES_PER_CELL,
            "lists": self.list_bytes,
        }


def grid_cell_count(scene: Scene) -> float:
    """Cells of the grid the solver builds over the domain (:class:`fluidsim.solver.DFSPHSolver`: cells of the
    support radius h, ``Z_SPLIT`` per h along z, padded by RETIRE_MARGIN_MAX spacings + h on every side)."""
    cfg = scene.config
    h = cfg.support_radius
    pad = RETIRE_MARGIN_MAX * cfg.spacing + h
    ext = np.subtract(scene.domain.max, scene.domain.min) + 2 * pad
    sizes = np.array([h, h, h / Z_SPLIT])
    return float(np.prod(np.maximum(np.ceil(ext / sizes - 1e-9), 1.0)))


def _ply_vertex_count(path: Path) -> float | None:
    """The ``element vertex N`` of a .ply header, None when the header does not say."""
    with open(path, "rb") as fh:
        head = fh.read(65536)
    for line in head.split(b"\n"):
        words = line.strip().split()
        if words[:2] == [b"element", b"vertex"] and len(words) == 3 and words[2].isdigit():
            return float(words[2])
        if words[:1] == [b"end_header"]:
            break
    return None


def _points_count(path: Path) -> float:
    """Points in a solid's point file (.npy shape, .ply header), else an upper bound of 12 bytes per point."""
    count = None
    try:
        if path.suffix.lower() == ".npy":
            count = float(np.load(path, mmap_mode="r", allow_pickle=False).shape[0])
        elif path.suffix.lower() == ".ply":
            count = _ply_vertex_count(path)
    except (OSError, ValueError, IndexError):
        count = None  # load_points reports what is wrong with the file when the solver is built
    return count if count is not None else float(path.stat().st_size // 12)


def _mesh_counts(path: Path, spacing: float, fill: bool) -> tuple[float, float]:
    """(particles, sampling bytes) of a mesh solid: the surface sample of ``area / (spacing^2 sqrt(3) / 2)``
    points plus, when filled, at most every point of its bounding-box lattice."""
    mesh = load_mesh(path)
    surface = max(1.0, mesh.get_surface_area() / (spacing * spacing * math.sqrt(3.0) / 2.0))
    sampling = surface * BYTES_PER_SURFACE_PARTICLE
    interior = 0.0
    if fill:
        box = mesh.get_axis_aligned_bounding_box()
        ext = np.asarray(box.max_bound) - np.asarray(box.min_bound)
        interior = float(np.prod(np.maximum(np.ceil(ext / spacing - 1e-6), 1.0)))
        sampling += interior * BYTES_PER_FILL_POINT
    return surface + interior, sampling


def estimate_scene_memory(scene: Scene) -> SceneMemory:
    """An upper estimate of the memory ``build_solver(scene)`` and its steps need (nothing large is allocated;
    mesh solids are read to measure their area and box).

    Args:
        scene: a validated scene.
    Returns:
        SceneMemory.
    Example:
        >>> est = estimate_scene_memory(load_scene("scene.json"))
        >>> est.bytes / 2**30  # GiB
    """
    spacing = scene.config.spacing
    fluid = sum(float(np.prod(lattice_counts(b.min, b.max, spacing))) for b in scene.fluid_blocks)
    walls = (
        float(wall_particle_count(scene.domain.min, scene.domain.max, spacing, scene.domain.wall_layers))
        if scene.domain.walls
        else 0.0
    )
    solids = sampling = 0.0
    for solid in scene.solids:
        if solid.points is not None:
            solids += _points_count(Path(scene.base_dir) / solid.points)
        else:
            count, extra = _mesh_counts(Path(scene.base_dir) / solid.mesh, spacing, solid.fill)
            solids, sampling = solids + count, sampling + extra
    cells = grid_cell_count(scene)
    lists = fluid * extra_list_slots(scene.config) * BYTES_PER_LIST_SLOT[scene.config.precision]
    total = fluid * BYTES_PER_FLUID + (walls + solids) * BYTES_PER_BOUNDARY + cells * BYTES_PER_CELL + sampling + lists
    return SceneMemory(
        fluid_particles=fluid,
        wall_particles=walls,
        solid_particles=solids,
        grid_cells=cells,
        sampling_bytes=sampling,
        bytes=float(total),
        list_bytes=float(lists),
    )


def default_list_capacity(config) -> int:
    """The neighbour-list slots per particle the solver allocates when ``max_neighbors`` is not set."""
    from .neighbors import lattice_neighbor_count, list_capacity  # noqa: PLC0415 - loads Taichi; the estimate does not

    return list_capacity(lattice_neighbor_count(config.spacing, config.support_radius))


def extra_list_slots(config) -> int:
    """Slots per particle that ``config.max_neighbors`` adds to the default capacity (0 when it is not set)."""
    if config.max_neighbors is None:
        return 0
    return max(0, int(config.max_neighbors) - default_list_capacity(config))


def _advice(scene: Scene, est: SceneMemory, limit: float) -> str:
    """What to change, after the item that costs most."""
    parts = est.parts()
    worst = max(parts, key=parts.get)
    r = scene.config.particle_radius
    if worst == "lists":
        return (
            f"most of it is the neighbour lists: 'solver.max_neighbors' = {scene.config.max_neighbors} slots for each "
            f"of {est.fluid_particles:.3g} fluid particles; remove 'max_neighbors' (the lists then follow the "
            f"largest neighbour count, {default_list_capacity(scene.config)} slots at rest) or set it much lower"
        )
    ext = np.subtract(scene.domain.max, scene.domain.min)
    size = " x ".join(f"{e:.6g}" for e in ext)
    # every count scales as 1 / r^3 or faster (walls and grid cells as 1 / r^2 and 1 / h^3): r (total/limit)^(1/3)
    # is the smallest particle radius that can fit
    larger_r = r * (est.bytes / limit) ** (1.0 / 3.0)
    radius = f"a particle_radius of about {larger_r:.3g} m or more (now {r:g} m)"
    layers = scene.domain.wall_layers
    if worst == "walls" and layers > Domain.wall_layers:
        reach = math.ceil(scene.config.support_radius / scene.config.spacing)
        return (
            f"most of it is the walls ({est.wall_particles:.3g} particles): 'domain.wall_layers' = {layers} layers; "
            f"the kernel reaches {reach} layers into a wall (h = {scene.config.support_radius:g} m), so set "
            f"'domain.wall_layers' to {max(reach, Domain.wall_layers)} (the default is {Domain.wall_layers})"
        )
    if worst in ("walls", "grid"):
        return (
            f"most of it is the {size} m domain ({est.wall_particles:.3g} wall particles, "
            f"{est.grid_cells:.3g} grid cells): shrink 'domain' to the region the fluid reaches, set "
            f"'domain.walls' to false if the fluid may leave, or use {radius}"
        )
    if worst == "fluid":
        return (
            f"most of it is the fluid ({est.fluid_particles:.3g} particles): make 'fluid_blocks' smaller or use "
            f"{radius}"
        )
    return (
        f"most of it is the solids ({est.solid_particles:.3g} particles): use coarser solid point files, "
        f"smaller meshes, 'fill': false, or {radius}"
    )


def check_scene_memory(scene: Scene, max_memory_gb: float | None = None, where: str = "the scene") -> SceneMemory:
    """Refuse, before anything is allocated, a scene whose solver would not fit in memory.

    Args:
        scene: a validated scene.
        max_memory_gb: the limit in GiB (None: the memory available now).
        where: names the scene in the message (its file).
    Returns:
        the estimate.
    Raises:
        SceneError: the estimate exceeds the limit; the message gives the estimate, its largest item and the fix.
    """
    if max_memory_gb is not None and not (math.isfinite(max_memory_gb) and max_memory_gb > 0):
        raise ValueError(f"--max-memory-gb must be a number of GiB > 0, got {max_memory_gb}")
    est = estimate_scene_memory(scene)
    limit = max_memory_gb * 2**30 if max_memory_gb is not None else float(available_memory_bytes())
    if est.bytes > limit:
        allowed = (
            f"the limit is {_gib(limit)} (--max-memory-gb)"
            if max_memory_gb is not None
            else f"only {_gib(limit)} are available (--max-memory-gb sets the limit)"
        )
        raise SceneError(
            f"{where} would need about {_gib(est.bytes)} ({est.fluid_particles:.3g} fluid, "
            f"{est.wall_particles + est.solid_particles:.3g} boundary particles, {est.grid_cells:.3g} grid cells at "
            f"particle_radius {scene.config.particle_radius:g} m) but {allowed}; {_advice(scene, est, limit)}"
        )
    return est


def _gib(nbytes: float) -> str:
    """A byte count in GiB, or TiB / PiB when large."""
    for unit, power in (("PiB", 50), ("TiB", 40)):
        if nbytes >= 2**power:
            return f"{nbytes / 2**power:.3g} {unit}"
    return f"{nbytes / 2**30:.3g} GiB"
