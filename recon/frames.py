"""World frames estimated from cameras: the scene's up direction (``--up auto``).

No paper equation is implemented here. The paper's code rotates Blender scenes by -90 deg about x
(z-up -> y-up); captures in arbitrary frames (COLMAP, SuperSplat exports such as the y-down biker) have
no such tag, so the up direction is estimated as nerfstudio's ``auto_orient_and_center_poses`` method
"up" does: the normalised mean of the cameras' up vectors, on the assumption that photographs are taken
mostly upright.

Convention. A :class:`recon.camera.Camera` holds world-to-camera ``[R | t]`` in the OpenCV axes (x right,
y down, z forward), so the rows of R are the camera axes in world coordinates and the camera's up
(image -y) in the world is ``-R[1, :]`` (``= -R^T[:, 1]``). This equals column 1 of the OpenGL
camera-to-world matrix (:meth:`Camera.opengl_c2w`), the vector nerfstudio averages.

Example:
    >>> from recon.camera_paths import orbit
    >>> up = up_from_cameras(orbit(8, 4.0, 20.0, 32, 32, 0.8, up_axis="z"))
    >>> bool(np.allclose(up, [0.0, 0.0, 1.0]))
    True
"""

from __future__ import annotations

import numpy as np
import torch


def camera_up_vectors(cameras) -> np.ndarray:
    """[n, 3] float64 unit up vectors (image -y) of ``cameras`` in world coordinates.

    Args:
        cameras: a sequence of :class:`recon.camera.Camera` (anything with a [4, 4] ``world_to_camera``).
    """
    cameras = list(cameras)
    if not cameras:
        raise ValueError("up_from_cameras: no cameras; the up direction is estimated from at least one camera")
    rows = [torch.as_tensor(c.world_to_camera, dtype=torch.float64)[1, :3] for c in cameras]
    return -torch.stack(rows).numpy()


def up_from_cameras(cameras, min_agreement: float = 0.25) -> np.ndarray:
    """The scene's up direction: the normalised mean of the cameras' world up vectors.

    Args:
        cameras: a sequence of :class:`recon.camera.Camera`.
        min_agreement: the smallest accepted norm of the mean of the unit up vectors, in (0, 1]: 1 when all
            cameras share one up, cos(e) for an orbit at elevation e, about 1/sqrt(n) for n random rolls.
    Returns:
        [3] float64 unit vector in world coordinates.
    Raises:
        ValueError: no cameras, or their up vectors disagree (the mean's norm is below ``min_agreement``:
            cameras rolled every way, no consistent up); the message names the fix, an explicit ``--up``.
    """
    if not 0.0 < min_agreement <= 1.0:
        raise ValueError(f"min_agreement must be in (0, 1], got {min_agreement}")
    ups = camera_up_vectors(cameras)
    mean = ups.mean(axis=0)
    norm = float(np.linalg.norm(mean))
    if norm < min_agreement:
        raise ValueError(
            f"the {len(ups)} cameras have no consistent up direction: their up vectors average to "
            f"length {norm:.3f} (< {min_agreement}; 1 = all agree); pass the up axis explicitly "
            "(--up y, --up z, ...) instead of --up auto"
        )
    return mean / norm
