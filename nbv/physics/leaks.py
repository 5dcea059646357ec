"""The leak measure: fluid particles that got deep inside the filled solid during a probe.

The solid is the lattice occupancy of :func:`nbv.physics.solidify.gaussians_to_solid` (filled by default). A fluid
particle is *inside* when its nearest lattice point (floor((x - lattice_min) / s + 1/2) per axis) is a
*deep-interior* point: solid, and its 6 neighbours solid too (a neighbour off the lattice counts as empty).
A particle pressed against the surface has the outer layer of solid points, or a free point, as its
nearest point: that is contact, not a leak. A particle more than about half a spacing past the outer layer
of a filled body is counted. A hollow or one-point-thick shell has no deep interior, so nothing in it ever
counts; the measure is meant for filled solids.

Counting at every step (:class:`nbv.physics.solid_kernels.LeakCounter`) is one Taichi kernel over the active fluid
particles (:func:`nbv.physics.solid_kernels.flag_deep_inside`) that adds into a per-step counter on the device;
nothing is read back until the probe ends. :func:`deep_inside_reference` is its numpy twin; this module holds the
measure's numpy side and its HDF5 rows, so that reading a RESULT.h5 loads no Taichi.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def deep_interior(occupancy: np.ndarray) -> np.ndarray:
    """[X, Y, Z] bool: solid points whose 6 neighbours are solid (points off the lattice are empty)."""
    occ = np.asarray(occupancy, dtype=bool)
    deep = occ.copy()
    for a in range(3):
        lo, hi, first, last = [slice(None)] * 3, [slice(None)] * 3, [slice(None)] * 3, [slice(None)] * 3
        lo[a], hi[a], first[a], last[a] = slice(None, -1), slice(1, None), 0, -1
        deep[tuple(lo)] &= occ[tuple(hi)]
        deep[tuple(hi)] &= occ[tuple(lo)]
        deep[tuple(first)] = False  # the neighbour off the lattice is empty
        deep[tuple(last)] = False
    return deep


def deep_inside_reference(x: np.ndarray, deep: np.ndarray, lattice_min: np.ndarray, spacing: float) -> np.ndarray:
    """Numpy twin of the kernel: [N] bool, the particles x [N, 3] (m) whose nearest lattice point is in ``deep``."""
    pts = np.asarray(x, dtype=np.float64).reshape(-1, 3)
    idx = np.floor((pts - np.asarray(lattice_min, np.float64)) * (1.0 / spacing) + 0.5).astype(np.int64)
    ok = np.all((idx >= 0) & (idx < np.asarray(deep.shape)), axis=1)
    out = np.zeros(len(pts), dtype=bool)
    out[ok] = deep[idx[ok, 0], idx[ok, 1], idx[ok, 2]]
    return out


@dataclass(frozen=True)
class ProbeLeaks:
    """One probe's end state and leak measure.

    Attributes:
        x_final: [F, 3] float32 final positions of the active fluid particles, sim metres, ordered by id.
        ids_final: [F] int32 their ids (index in the probe's initial fluid set).
        leaked_ids: [K] int32 ids of the particles inside the solid at the end (a subset of ``ids_final``).
        per_step: [S] int32 particles inside after each step (S = the probe's steps).
    """

    x_final: np.ndarray
    ids_final: np.ndarray
    leaked_ids: np.ndarray
    per_step: np.ndarray

    @property
    def final(self) -> int:
        """Particles inside the solid at the end."""
        return int(len(self.leaked_ids))

    @property
    def max(self) -> int:
        """The most particles inside at any step (0 without steps)."""
        return int(self.per_step.max()) if len(self.per_step) else 0

    @property
    def max_step(self) -> int:
        """The first step (0-based) with :attr:`max` particles inside (-1 without steps)."""
        return int(np.argmax(self.per_step)) if len(self.per_step) else -1


def write_probe_leaks(group, leaks: ProbeLeaks) -> None:
    """Write ``leaks`` into an h5py group ``/probes/<dir>`` (layout in :func:`nbv.physics.save_result`)."""
    ds = group.create_dataset("leaked", data=np.asarray(leaks.leaked_ids, np.int32))
    ds.attrs["final"], ds.attrs["max"], ds.attrs["max_step"] = leaks.final, leaks.max, leaks.max_step
    group.create_dataset("leaked_per_step", data=np.asarray(leaks.per_step, np.int32))
    group.create_dataset(
        "x_final", data=np.asarray(leaks.x_final, np.float32).reshape(-1, 3), compression="gzip", compression_opts=1
    )
    group.create_dataset(
        "ids_final", data=np.asarray(leaks.ids_final, np.int32), compression="gzip", compression_opts=1
    )


def read_probe_leaks(group) -> ProbeLeaks:
    """Inverse of :func:`write_probe_leaks`."""
    per_step = group["leaked_per_step"][()] if "leaked_per_step" in group else np.zeros(0, np.int32)
    return ProbeLeaks(
        x_final=group["x_final"][()],
        ids_final=group["ids_final"][()],
        leaked_ids=group["leaked"][()],
        per_step=per_step,
    )
