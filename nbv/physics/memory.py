"""The memory a probe run needs, estimated before anything is allocated (:func:`estimate_memory`,
:func:`check_memory`), and the message that names the fix when it does not fit."""

from __future__ import annotations

import numpy as np

from fluidsim.host import available_memory_bytes
from nbv.physics import floaters
from nbv.physics.aggregate import GaussianAccumulator, reach_classes
from nbv.physics.config import QUICK, PhysicsConfig
from nbv.physics.lattice import BYTES_PER_GAUSSIAN as BYTES_PER_GAUSSIAN_SOLIDIFY
from nbv.physics.lattice import estimate_solidify_bytes
from nbv.physics.plan import ProbePlan, RunFrame

# Memory per fluid particle of one probe (solver state, pressure-solver arrays, fluid and boundary neighbour lists)
# and per boundary particle (walls and solid), doubled for headroom: the peak resident memory of probes around a
# solid sphere (-x, f32, 2 threads, 20 steps, after the JIT) grew by 1,050-1,140 B per fluid particle with their
# boundary (r = 0.04-0.02 m, 12k-106k fluid and 32k-154k boundary particles), of which about 130 B per boundary
# particle. The per-Gaussian accumulator is estimated apart (nbv.physics.aggregate.GaussianAccumulator.estimate_bytes).
BYTES_PER_FLUID = 2048

BYTES_PER_BOUNDARY = 256

# Per Gaussian, held through the whole run besides the Gaussian set itself: simulation-frame means, covariances and
# reach (float64, 104 B), and per probe the result rows (means, counts, distinct counts: 24 B).
BYTES_PER_GAUSSIAN_RUN = 104

BYTES_PER_GAUSSIAN_PROBE = 24

BYTES_PER_LATTICE_POINT = 2

# Per Gaussian and replica, with PhysicsConfig.replicas > 1 (nbv.physics.replicas): each replica's result is held until
# they are combined (D_g max and mean 16 B, with a crop its own centres, covariances and reach 104 B) and so are its
# rows in the combined result's ReplicaRuns (reached 1 B, rounded up to 8).
BYTES_PER_GAUSSIAN_REPLICA = 128

# Per Gaussian, probe and replica: the result's rows (D_g^(IC), samples, distinct counts, empty-scene D_g^(IC): 32 B)
# and the ReplicaRuns rows (D_g^(IC) and distinct counts: 16 B).
BYTES_PER_GAUSSIAN_REPLICA_PROBE = 48


def estimate_memory(frame: RunFrame, plan: ProbePlan | None = None) -> dict[str, float]:
    """An upper estimate of the memory one probe of ``frame`` (:class:`nbv.physics.plan.RunFrame`) needs, before any
    probe is allocated.

    Without ``plan`` it is cheap, before the solid exists: the probes are laid out around the frame's lattice
    (:meth:`nbv.physics.plan.ProbePlan.bound`: the box of the Gaussians' 3-sigma boxes where they can make solid, a
    Gaussian with opacity < tau clipped to the others' box, those under tau / 10 left out,
    :mod:`nbv.physics.floaters`). With the ``plan`` around the real solid (:meth:`nbv.physics.plan.ProbePlan.of`) it
    is exact, and smaller when faint or scattered Gaussians widen the box but make no solid. Uses the per-particle
    byte counts ``BYTES_PER_*`` and the lattice's size (:attr:`nbv.physics.plan.RunFrame.lattice`).

    The bytes add the Gaussians held all run, and with ``config.replicas`` > 1 the replicas' per-Gaussian arrays, to
    the larger of the solidification's peak (:func:`nbv.physics.lattice.estimate_solidify_bytes`) and one probe's
    (its solver, and the per-Gaussian accumulator's :meth:`nbv.physics.aggregate.GaussianAccumulator.estimate_bytes`);
    the replicas run one after another, so the peak of one probe does not grow with them.

    Returns:
        dict: lattice_points, fluid_particles (largest probe), boundary_particles, and the bytes (floats): the
        Gaussian set and the per-Gaussian arrays held all run (``resident_bytes``), the replicas' arrays
        (``replica_bytes``, 0 for one run), the solidification's peak (``solidify_bytes``), one probe's solver
        (``probe_bytes``) and its accumulator (``accumulator_bytes``), and ``bytes`` = resident + replicas + the
        larger of the two phases.
    Example:
        >>> estimate_memory(RunFrame.of(gaussians, PhysicsConfig.quick()))["bytes"]  # doctest: +SKIP
    """
    plan = ProbePlan.bound(frame) if plan is None else plan
    config, spacing = frame.config, plan.spacing
    probe = config.probe_config()
    fluid = boundary = 0
    for d in config.directions:
        s = plan.setups[d]
        f = float(np.prod(np.floor((np.subtract(s.fluid_max, s.fluid_min)) / spacing)))
        ext = np.subtract(s.domain_max, s.domain_min)
        area = 2 * (ext[0] * ext[1] + ext[1] * ext[2] + ext[0] * ext[2])
        walls = area * probe.wall_layers / spacing**2
        fluid, boundary = max(fluid, int(f)), max(boundary, int(walls) + plan.solid_count)
    lattice, gaussians = int(frame.lattice.points), frame.sim.gaussians
    g = int(gaussians.num)
    tensors = (gaussians.means, gaussians.quats, gaussians.log_scales, gaussians.opacity_logits, gaussians.sh)
    resident = sum(t.numel() * t.element_size() for t in tensors) + g * (
        BYTES_PER_GAUSSIAN_RUN + BYTES_PER_GAUSSIAN_PROBE * len(config.directions)
    )
    # each replica's result is held until they are combined (nbv.physics.replicas); one run keeps none
    per_replica = BYTES_PER_GAUSSIAN_REPLICA + BYTES_PER_GAUSSIAN_REPLICA_PROBE * len(config.directions)
    replicas = 0.0 if config.replicas == 1 else float(config.replicas) * float(g) * per_replica
    solidify = estimate_solidify_bytes(g, lattice)
    probe_bytes = fluid * BYTES_PER_FLUID + boundary * BYTES_PER_BOUNDARY + lattice * BYTES_PER_LATTICE_POINT
    radii = gaussians.log_scales.detach().max(dim=1).values.double().exp().cpu().numpy()  # ratios: scale-free
    accumulator = GaussianAccumulator.estimate_bytes(
        g,
        fluid,
        config.track_distinct,
        float_bytes=4 if config.precision == "f32" else 8,
        num_levels=reach_classes(radii),
    )
    return {
        "lattice_points": lattice,
        "fluid_particles": fluid,
        "boundary_particles": boundary,
        "resident_bytes": float(resident),
        "replica_bytes": float(replicas),
        "solidify_bytes": float(solidify),
        "probe_bytes": float(probe_bytes),
        "accumulator_bytes": float(accumulator),
        "bytes": float(resident + replicas + max(solidify, probe_bytes + accumulator)),
    }


def check_memory_bound(frame: RunFrame) -> bool:
    """The cheap memory check of a run (:class:`nbv.physics.plan.RunFrame`), before its solid exists.

    The bound from the Gaussians' box decides first; when it does not fit but the lattice does, the solid is
    computed and the probes are checked around it (:func:`check_memory` with the solid's plan), since scattered faint
    Gaussians widen the box without making solid.

    Returns:
        whether the exact check must follow once the solid exists.
    Raises:
        ValueError: the solid itself would not fit (its lattice or its computation), with the estimate and the fix.
    """
    config = frame.config
    cheap = estimate_memory(frame)
    exact = cheap["bytes"] > memory_limit_bytes(config)
    if exact and (
        cheap["lattice_points"] > frame.solid_config.max_points
        or cheap["resident_bytes"] + cheap["replica_bytes"] + cheap["solidify_bytes"] > memory_limit_bytes(config)
    ):
        _refuse_over_limit(frame, cheap)  # the solid is too costly: raise
    return exact


def memory_limit_bytes(config: PhysicsConfig) -> float:
    """The memory a probe may use: ``config.max_memory_gb``, or the memory available now."""
    return config.max_memory_gb * 2**30 if config.max_memory_gb is not None else float(available_memory_bytes())


def check_memory(frame: RunFrame, plan: ProbePlan | None = None) -> dict[str, float]:
    """Raise ValueError, with the estimate and the fix, when a probe of ``frame`` would not fit in memory; else return
    :func:`estimate_memory` (``plan``: the probes around the solid, for the exact check; None: the cheap bound)."""
    est = estimate_memory(frame, plan)
    _refuse_over_limit(frame, est)
    return est


def _refuse_over_limit(frame: RunFrame, est: dict[str, float]) -> None:
    """The ValueError of :func:`check_memory` when the estimate ``est`` exceeds the limit."""
    config, num = frame.config, frame.sim.num
    limit = memory_limit_bytes(config)
    if est["bytes"] <= limit:
        return
    available = "allowed (--max-memory-gb)" if config.max_memory_gb is not None else "available"
    gib = {
        k: est[k] / 2**30
        for k in ("resident_bytes", "replica_bytes", "solidify_bytes", "probe_bytes", "accumulator_bytes")
    }
    replicas = (
        f", {gib['replica_bytes']:.3g} GiB for the {config.replicas} replicas' per-Gaussian arrays"
        if est["replica_bytes"]
        else ""
    )
    raise ValueError(
        f"the probe would need about {est['bytes'] / 2**30:.4g} GiB ({_count(est['fluid_particles'])} fluid and "
        f"{_count(est['boundary_particles'])} boundary particles at r = {config.particle_radius} m, a solid "
        f"lattice of {_count(est['lattice_points'])} points, {num:,} Gaussians: "
        f"{gib['resident_bytes']:.3g} GiB for the Gaussians{replicas}, then {gib['solidify_bytes']:.3g} GiB to "
        f"solidify, {gib['probe_bytes']:.3g} GiB per probe and "
        f"{gib['accumulator_bytes']:.3g} GiB for its per-Gaussian accumulator) but {limit / 2**30:.3g} GiB are "
        f"{available}{_memory_fix(frame, est, limit)}"
    )


def _count(n: float) -> str:
    """A count with thousands separators, or in powers of ten when it is too large to read (1.65e+114)."""
    return f"{int(n):,}" if n < 1e12 else f"{float(n):.3g}"


def _memory_fix(frame: RunFrame, est: dict[str, float], limit: float) -> str:
    """The advice of :func:`check_memory`: fewer replicas when they alone make the difference, else the Gaussian
    that alone widens the lattice, if one does (a larger radius cannot help then), else the particle radius that
    would fit, if the object is still resolved."""
    config, num = frame.config, frame.sim.num
    if est["replica_bytes"] and est["bytes"] - est["replica_bytes"] <= limit:
        per_replica = est["replica_bytes"] / config.replicas
        fits = max(1, int((limit - (est["bytes"] - est["replica_bytes"])) // per_replica))
        return (
            f"; --replicas {config.replicas} is too many for this memory: each replica keeps "
            f"{per_replica / 2**30:.3g} GiB of per-Gaussian arrays, so use --replicas {fits} or fewer, or allow more "
            "memory (--max-memory-gb)"
        )
    sim, lattice = frame.sim, frame.lattice
    note = floaters.dominant_note(
        *lattice.boxes, lattice.spacing, sim.means, sim.covariances, sim.opacities, sim.transform
    )
    if note:
        return f"{note.replace('widens it', 'widens the solid lattice')}; a larger particle radius cannot help"
    # the Gaussians' own bytes do not shrink with a larger radius
    fixed = est["resident_bytes"] + max(est["accumulator_bytes"], float(num) * BYTES_PER_GAUSSIAN_SOLIDIFY)
    if fixed >= limit:
        return (
            f"; the {num:,} Gaussians alone need about {fixed / 2**30:.3g} GiB (the set, the "
            "per-Gaussian accumulator or the solidification), so a larger particle radius cannot help: crop "
            "them to the object (--crop auto, or --crop xmin,ymin,zmin,xmax,ymax,zmax in scene units), prune "
            "them, or allow more memory (--max-memory-gb) on a larger machine"
        )
    # the fluid and the lattice (the rest of the bytes) scale as 1 / r^3: the radius that would fit, if the object
    # stays resolved
    radius = config.particle_radius * ((est["bytes"] - fixed) / (limit - fixed)) ** (1.0 / 3.0)
    extent = float(np.max(np.subtract(*lattice.extent[::-1])))
    if 2.0 * radius <= extent / 4.0:
        return (
            f"; use a particle radius of about {radius:.3g} m or more (--particle-radius; --quick is "
            f"{QUICK['particle_radius']} m), a smaller scale (--scale), or crop the Gaussians (--crop)"
        )
    return (
        f"; a particle radius that fits ({radius:.3g} m) would leave the {extent:.3g} m solid box fewer than 4 "
        "particles across: crop the Gaussians to the object (--crop auto, or --crop xmin,ymin,zmin,xmax,ymax,zmax "
        "in scene units) or use a smaller scale (--scale)"
    )
