"""The candidate cameras in the simulation frame, with their view scores S(T) and ranks from scores.json.

A camera of a Blender / NeRF ``transforms.json`` (:func:`recon.datasets.load_cameras`, OpenCV axes: x right,
y down, z forward; scene units) is moved to the simulation frame by RESULT.h5's ``scene_to_sim`` M = [s R | t]:
its centre c -> s R c + t, its axes -> R (camera-to-world rotation). viser's frustums and viewport cameras use
the same OpenCV axes, so the pose is handed to them as it is. Scores come from `fluidgs score`'s JSON (its
``views``: index in the cameras file, name, score, rank).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fluidsim.files import read_json


@dataclass(frozen=True)
class CandidateView:
    """One candidate camera, simulation frame.

    Attributes:
        index: its index in the cameras file. name: its name (the image stem).
        position: [3] centre, sim metres. rotation: [3, 3] camera-to-world (OpenCV axes). wxyz: [4] the same.
        fov_y: vertical field of view, rad. aspect: width / height.
        score: S(T) from scores.json, or None. rank: 1 = best, or None.
        coverage: A(T) from scores.json, or None. physics_mean: S(T) / A(T), or None.
        uncertainty_png: the view's physics-uncertainty picture (``score --uncertainty-images``), or None.
        png: the view's picture written by `fluidgs score` (render | D_g heat-map), or None.
    """

    index: int
    name: str
    position: np.ndarray
    rotation: np.ndarray
    wxyz: np.ndarray
    fov_y: float
    aspect: float
    score: float | None = None
    rank: int | None = None
    coverage: float | None = None
    physics_mean: float | None = None
    uncertainty_png: Path | None = None
    png: Path | None = None

    @property
    def forward(self) -> np.ndarray:
        """[3] the viewing direction (camera +z), sim frame."""
        return self.rotation[:, 2].copy()


def rotation_to_wxyz(rotation: np.ndarray) -> np.ndarray:
    """[3, 3] rotation matrix -> [4] unit quaternion (w, x, y, z) with w >= 0 (Shepperd's method)."""
    m = np.asarray(rotation, np.float64)
    tr = float(np.trace(m))
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + m[i, i] - m[j, j] - m[k, k], 1e-300))
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    out = np.asarray(q, np.float64)
    out /= np.linalg.norm(out)
    return out if out[0] >= 0 else -out


def split_scene_to_sim(matrix: np.ndarray, where: str) -> tuple[float, np.ndarray, np.ndarray]:
    """M = [s R | t] -> (s, R [3, 3], t [3]); ValueError naming ``where`` when the 3 x 3 part is no scaled rotation."""
    m = np.asarray(matrix, np.float64)
    lin = m[:3, :3]
    det = float(np.linalg.det(lin))
    if not det > 0:
        raise ValueError(f"{where}: scene_to_sim has a 3x3 part of determinant {det:.3g}; it must be a scaled rotation")
    s = det ** (1.0 / 3.0)
    rot = lin / s
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6):
        raise ValueError(f"{where}: the 3x3 part of scene_to_sim is not a scaled rotation")
    return s, rot, m[:3, 3].copy()


def read_scores(path: str | Path) -> dict:
    """scores.json of `fluidgs score` (or the demo): ValueError naming the file when it is not one."""
    p = Path(path)
    fix = f"write it with `fluidgs score GAUSSIANS.ply --cameras transforms.json --result RESULT.h5 -o {p}`"
    data = read_json(p, "--scores", fix)
    views = data.get("views") if isinstance(data, dict) else None
    if not isinstance(views, list) or not all(
        isinstance(v, dict) and {"index", "score", "rank"} <= set(v) for v in views
    ):
        raise ValueError(
            f"--scores {p} has no list 'views' of {{index, name, score, rank}}; pass the scores.json of `fluidgs score`"
        )
    return data


def cameras_path_of(scores: dict, scores_path: Path) -> Path | None:
    """The cameras file a scores.json names (as written, else beside the JSON), or None when neither exists."""
    name = scores.get("cameras")
    if not isinstance(name, str) or not name:
        return None
    for candidate in (Path(name), scores_path.parent / Path(name).name):
        if candidate.exists():  # a file, or a COLMAP model folder
            return candidate
    return None


def _optional_float(row: dict | None, key: str) -> float | None:
    value = None if row is None else row.get(key)
    return None if value is None else float(value)


def _uncertainty_png(row: dict | None) -> Path | None:
    """The uncertainty picture a scores.json row names, when that file exists."""
    image = None if row is None else row.get("uncertainty_image")
    path = Path(image["png"]) if isinstance(image, dict) and isinstance(image.get("png"), str) else None
    return path if path is not None and path.is_file() else None


def candidate_views(
    cameras: str | Path, scene_to_sim: np.ndarray, scores: dict | None = None, where: str = "RESULT.h5"
) -> list[CandidateView]:
    """The cameras of ``cameras`` (transforms.json) in the simulation frame, with scores and ranks.

    Args:
        cameras: a camera file of :func:`recon.camera_files.load_camera_file` (transforms.json, COLMAP model,
            graphdeco cameras.json), scene units (the Gaussians' frame).
        scene_to_sim: [4, 4] RESULT.h5's transform. where: RESULT.h5's name, for messages.
        scores: the parsed scores.json (:func:`read_scores`), or None.
    Returns:
        one per camera, in file order.
    Raises:
        ValueError: a malformed cameras file, or scores of other cameras (an index past the file's cameras, or a
            name that differs).
    """
    from recon.camera_files import load_camera_file  # noqa: PLC0415 - torch: imported here so viz.cameras stays light

    cams = load_camera_file(cameras)
    s, rot, t = split_scene_to_sim(scene_to_sim, where)
    by_index: dict[int, dict] = {}
    if scores is not None:
        for v in scores["views"]:
            i = int(v["index"])
            if not 0 <= i < len(cams):
                raise ValueError(
                    f"--scores ranks camera {i} but {cameras} has {len(cams)} cameras; pass the cameras "
                    "file the scores were computed for (--cameras)"
                )
            if "name" in v and str(v["name"]) != cams[i].name:
                raise ValueError(
                    f"--scores names camera {i} {v['name']!r} but {cameras} calls it {cams[i].name!r}; "
                    "pass the cameras file the scores were computed for (--cameras)"
                )
            by_index[i] = v
    out = []
    for i, cam in enumerate(cams):
        c2w = cam.camera_to_world.numpy()
        r = rot @ c2w[:3, :3]
        v = by_index.get(i)
        out.append(
            CandidateView(
                index=i,
                name=cam.name,
                position=s * (rot @ c2w[:3, 3]) + t,
                rotation=r,
                wxyz=rotation_to_wxyz(r),
                fov_y=float(cam.fov_y),
                aspect=cam.width / cam.height,
                score=None if v is None else float(v["score"]),
                rank=None if v is None else int(v["rank"]),
                coverage=_optional_float(v, "coverage"),
                physics_mean=_optional_float(v, "physics_mean"),
                uncertainty_png=_uncertainty_png(v),
            )
        )
    return out


UNSAFE_NAME = re.compile(r"[^A-Za-z0-9._+-]+")
MAX_NAME_CHARS = 80  # of a camera's name in its file name: the name is the camera's, the file stays short


def view_file_stem(rank: int, index: int, name: str) -> str:
    """``rank001_004_<name>``, the stem of a view's files in a views folder (`fluidgs score` writes them, the viewer
    reads them): the camera's name (graphdeco's ``img_name`` may hold ``/`` or 300 characters) with every run of
    characters other than letters, digits and ``._+-`` turned into ``_`` and cut to :data:`MAX_NAME_CHARS`, so the
    file lands in the views folder whatever the name (the rank and the index keep it unique)."""
    safe = UNSAFE_NAME.sub("_", str(name)).strip("._")[:MAX_NAME_CHARS] or "view"
    return f"rank{rank:03d}_{index:03d}_{safe}"


def view_png(scores_path: str | Path, view: CandidateView) -> Path | None:
    """The picture `fluidgs score` wrote of ``view`` in its default folder ``<scores stem>_views`` (named
    ``rank<r>_<index>_<name>.png``), or None."""
    if view.rank is None:
        return None
    p = Path(scores_path)
    png = p.with_name(p.stem + "_views") / f"{view_file_stem(view.rank, view.index, view.name)}.png"
    return png if png.is_file() else None
