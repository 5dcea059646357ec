"""Camera generators: orbits, rings around an object and random poses on a sphere, all looking at a target.

No paper equation is implemented here. The paper's DrivAerNet++ datasets (appendix, "Rendering") place
the cameras on a sphere of radius 6 around an object fitted to a bounding box of 4, in random order;
:func:`random_sphere` draws such poses, :func:`orbit` gives evenly spaced ones for videos and previews.

Conventions. Positions are ``target + radius * d`` for unit directions d. The up axis ("y" or "z") is
the scene's up direction: every camera looks at the target with the up axis pointing up in the image
(:meth:`recon.camera.Camera.look_at`). A camera exactly on the up axis (looking straight down or up)
has no defined image-up; :meth:`Camera.look_at` then picks a fixed perpendicular, so the pose is still
deterministic. Directions uniform on the sphere are normalised standard Gaussian vectors; the upper
hemisphere folds them with the absolute value of the up coordinate, which keeps them uniform there.

Rings around an object (:func:`orbit_rings`, the candidate cameras of a capture that comes without any): the
object is a sphere of radius r about a centre c (the caller's object box, e.g. the robust box of
:mod:`nbv.orbit`). Each ring has one elevation e above the plane through c normal to ``up``; its cameras sit
at azimuths 2 pi (j + o) / m (j = 0..m-1, o = 1/2 on every second ring, so the rings interleave), measured from
``front`` towards ``up x front`` (counter-clockwise seen from above), at the distance
d = r / sin(min(fov_x, fov_y) / 2): the whole sphere, hence the whole object, lies inside the view cone of the
narrower field of view and touches it. Every camera looks at c with ``up`` up in the image.

Example:
    >>> cams = random_sphere(8, radius=6.0, width=64, height=64, fov_x=0.8, seed=0, hemisphere=True)
    >>> len(cams), cams[0].width
    (8, 64)
"""

from __future__ import annotations

import math

import numpy as np

from .camera import Camera

UP_AXES = {"y": 1, "z": 2}


def up_vector(up_axis: str) -> np.ndarray:
    """[3] unit vector of the up axis ("y" or "z")."""
    if up_axis not in UP_AXES:
        raise ValueError(f"up_axis must be 'y' or 'z', got {up_axis!r}")
    up = np.zeros(3)
    up[UP_AXES[up_axis]] = 1.0
    return up


def _check_common(n: int, radius: float, width: int, height: int, fov_x: float, target) -> np.ndarray:
    if int(n) != n or n < 1:
        raise ValueError(f"n (number of cameras) must be a positive integer, got {n}")
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be finite and > 0, got {radius}")
    if not 0 < fov_x < math.pi:
        raise ValueError(f"fov_x must be in (0, pi) radians, got {fov_x}")
    for key, val in (("width", width), ("height", height)):
        if int(val) != val or val < 1:
            raise ValueError(f"{key} must be a positive integer (pixels), got {val}")
    target = np.asarray(target, dtype=np.float64).reshape(-1)
    if target.shape != (3,) or not np.isfinite(target).all():
        raise ValueError(f"target must be 3 finite numbers, got {target.tolist()}")
    return target


def cameras_from_directions(
    directions: np.ndarray,
    radius: float,
    width: int,
    height: int,
    fov_x: float,
    up_axis: str = "y",
    target=(0.0, 0.0, 0.0),
    prefix: str = "cam",
) -> list[Camera]:
    """Cameras at ``target + radius * directions[i]`` looking at ``target``.

    Args:
        directions: [n, 3] unit vectors (world frame).
        radius: distance from the target, scene units.
        width, height: image size, pixels. fov_x: horizontal field of view, radians.
        up_axis: "y" or "z", the direction shown up in the images.
        target: [3] point every camera looks at.
        prefix: camera names are ``f"{prefix}_{i:03d}"``.
    Returns:
        list of n :class:`Camera`.
    """
    target = _check_common(len(directions), radius, width, height, fov_x, target)
    up = up_vector(up_axis)
    directions = np.asarray(directions, dtype=np.float64)
    if directions.ndim != 2 or directions.shape[1] != 3:
        raise ValueError(f"directions must have shape [n, 3], got {tuple(directions.shape)}")
    return [
        Camera.look_at(target + radius * d, target, up, width, height, fov_x, name=f"{prefix}_{i:03d}")
        for i, d in enumerate(directions)
    ]


def orbit(
    n: int,
    radius: float,
    elevation_deg: float,
    width: int,
    height: int,
    fov_x: float,
    up_axis: str = "y",
    target=(0.0, 0.0, 0.0),
) -> list[Camera]:
    """n cameras evenly spaced in azimuth on a circle of constant elevation around the up axis.

    Args:
        n: number of cameras.
        radius: distance from the target, scene units.
        elevation_deg: angle above the horizontal plane through the target, degrees in [-90, 90].
        width, height: image size, pixels. fov_x: horizontal field of view, radians.
        up_axis: "y" or "z". With "y" the first camera sits on +z; with "z" on +x.
        target: [3] point the cameras look at.
    Returns:
        list of n :class:`Camera`, azimuth increasing counter-clockwise seen from above.
    """
    _check_common(n, radius, width, height, fov_x, target)
    if not -90.0 <= elevation_deg <= 90.0:
        raise ValueError(f"elevation_deg must be in [-90, 90] degrees, got {elevation_deg}")
    el = math.radians(elevation_deg)
    az = 2.0 * math.pi * np.arange(n) / n
    horizontal_a, horizontal_b = math.cos(el) * np.cos(az), math.cos(el) * np.sin(az)
    vertical = np.full(n, math.sin(el))
    if up_axis == "y":  # right-handed (z, x, y): counter-clockwise seen from +y
        dirs = np.stack([horizontal_b, vertical, horizontal_a], axis=1)
    else:  # (x, y, z): counter-clockwise seen from +z
        dirs = np.stack([horizontal_a, horizontal_b, vertical], axis=1)
    return cameras_from_directions(dirs, radius, width, height, fov_x, up_axis, target, prefix="orbit")


def orbit_around(
    points: np.ndarray, n: int, width: int, elevation_deg: float = 20.0, fov_x: float = math.radians(50.0)
) -> list[Camera]:
    """An :func:`orbit` of n cameras around ``points`` [N, 3]: aimed at their bounding box's centre, at 1.6 x its
    largest extent (scene units), ``width`` x ``3/4 width`` pixels (the candidate views of ``fluidgs demo``)."""
    points = np.asarray(points, dtype=np.float64)
    lo, hi = points.min(axis=0), points.max(axis=0)
    extent = float((hi - lo).max())
    return orbit(n, 1.6 * extent, elevation_deg, width, int(width * 3 / 4), fov_x, target=tuple((lo + hi) / 2))


# Defaults of the rings of candidate cameras around a capture: the horizontal field of view, the elevations of the
# rings above the horizon and the image aspect (height / width).
ORBIT_FOV_X_DEG = 50.0
ORBIT_ELEVATIONS_DEG = (15.0, 45.0)
ORBIT_ASPECT = 0.75


def framing_distance(radius: float, fov_x: float, width: int, height: int) -> float:
    """The distance at which a sphere of ``radius`` just fits the narrower field of view of a pinhole camera of
    ``width`` x ``height`` pixels with horizontal field of view ``fov_x`` (radians): r / sin(min(fov_x, fov_y) / 2),
    with tan(fov_y / 2) = (height / width) tan(fov_x / 2) (square pixels)."""
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be finite and > 0, got {radius}")
    if not 0 < fov_x < math.pi:
        raise ValueError(f"fov_x must be in (0, pi) radians, got {fov_x}")
    fov_y = 2.0 * math.atan(height / width * math.tan(0.5 * fov_x))
    return radius / math.sin(0.5 * min(fov_x, fov_y))


def ring_counts(n: int, rings: int) -> list[int]:
    """Cameras per ring: n split over ``rings`` as evenly as possible, the first rings taking one more."""
    if int(n) != n or n < 1:
        raise ValueError(f"n (number of cameras) must be a positive integer, got {n}")
    return [n // rings + (1 if k < n % rings else 0) for k in range(rings)]


def orbit_rings(
    n: int,
    centre,
    radius: float,
    up,
    front,
    elevations_deg,
    width: int,
    height: int,
    fov_x: float,
    prefix: str = "orbit",
) -> list[Camera]:
    """n cameras on rings around a sphere (the object), each looking at its centre with ``up`` up in the image.

    Args:
        n: number of cameras, split over the rings by :func:`ring_counts`.
        centre: [3] the object's centre (the target), scene units.
        radius: the object's bounding-sphere radius, scene units; the cameras sit at :func:`framing_distance`.
        up: [3] the scene's up direction (any length > 0).
        front: [3] azimuth 0 (its part normal to ``up`` is used; it must not be parallel to ``up``).
        elevations_deg: one elevation per ring, degrees in (-90, 90), above the plane normal to ``up``.
        width, height: image size, pixels. fov_x: horizontal field of view, radians.
        prefix: camera names are ``f"{prefix}_{i:03d}"``, ring by ring, azimuth increasing.
    Returns:
        list of n :class:`Camera`.
    """
    centre = _check_common(n, radius, width, height, fov_x, centre)
    elevations = [float(e) for e in elevations_deg]
    if not elevations or not all(-90.0 < e < 90.0 for e in elevations):
        raise ValueError(
            f"elevations must be one or more angles in (-90, 90) degrees, got {elevations}; a camera "
            "on the up axis has no upright image"
        )
    up = np.asarray(up, dtype=np.float64).reshape(3)
    if not (np.isfinite(up).all() and np.linalg.norm(up) > 0):
        raise ValueError(f"up must be a finite non-zero 3-vector, got {up.tolist()}")
    up = up / np.linalg.norm(up)
    front = np.asarray(front, dtype=np.float64).reshape(3)
    front = front - (front @ up) * up
    if not np.linalg.norm(front) > 1e-9:
        raise ValueError("front must not be parallel to up")
    front = front / np.linalg.norm(front)
    side = np.cross(up, front)
    distance = framing_distance(radius, fov_x, width, height)
    cams: list[Camera] = []
    for k, (elevation, count) in enumerate(zip(elevations, ring_counts(n, len(elevations)), strict=True)):
        el = math.radians(elevation)
        for j in range(count):
            az = 2.0 * math.pi * (j + 0.5 * (k % 2)) / count
            d = math.cos(el) * (math.cos(az) * front + math.sin(az) * side) + math.sin(el) * up
            cams.append(
                Camera.look_at(
                    centre + distance * d, centre, up, width, height, fov_x, name=f"{prefix}_{len(cams):03d}"
                )
            )
    return cams


def sphere_directions(n: int, seed: int, hemisphere: bool = False, up_axis: str = "y") -> np.ndarray:
    """[n, 3] unit vectors uniform on the sphere (or the upper hemisphere w.r.t. ``up_axis``).

    Normalised standard Gaussian vectors from ``numpy.random.default_rng(seed)``; for the hemisphere the
    up coordinate is replaced by its absolute value (a measure-preserving fold of the sphere).
    """
    if int(n) != n or n < 1:
        raise ValueError(f"n (number of directions) must be a positive integer, got {n}")
    axis = UP_AXES.get(up_axis)
    if axis is None:
        raise ValueError(f"up_axis must be 'y' or 'z', got {up_axis!r}")
    rng = np.random.default_rng(seed)
    dirs = rng.standard_normal((n, 3))
    norms = np.linalg.norm(dirs, axis=1, keepdims=True)
    while (norms < 1e-12).any():  # probability ~0; redraw rather than divide by zero
        bad = norms[:, 0] < 1e-12
        dirs[bad] = rng.standard_normal((int(bad.sum()), 3))
        norms = np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs = dirs / norms
    if hemisphere:
        dirs[:, axis] = np.abs(dirs[:, axis])
    return dirs


def random_sphere(
    n: int,
    radius: float,
    width: int,
    height: int,
    fov_x: float,
    seed: int,
    hemisphere: bool = False,
    up_axis: str = "y",
    target=(0.0, 0.0, 0.0),
) -> list[Camera]:
    """n cameras at random positions on a sphere (or upper hemisphere) around ``target``, looking at it.

    Args:
        n: number of cameras.
        radius: distance from the target, scene units.
        width, height: image size, pixels. fov_x: horizontal field of view, radians.
        seed: seed of the numpy Generator; the same seed gives the same cameras.
        hemisphere: keep only positions whose up coordinate (relative to the target) is >= 0.
        up_axis: "y" or "z".
        target: [3] point the cameras look at.
    Returns:
        list of n :class:`Camera` named ``view_000``, ``view_001``, ...
    """
    _check_common(n, radius, width, height, fov_x, target)
    dirs = sphere_directions(n, seed, hemisphere, up_axis)
    return cameras_from_directions(dirs, radius, width, height, fov_x, up_axis, target, prefix="view")
