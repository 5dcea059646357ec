"""Reading trained models as the trainers save them: gsplat ``ckpt_*.pt`` and nerfstudio splatfacto ``step-*.ckpt``,
and restoring the metric frame the trainers normalised away.

**gsplat** (``examples/simple_trainer.py``) saves ``{"step", "splats": {...}}`` per rank as
``ckpt_<step>_rank<r>.pt``; every rank holds a share of the Gaussians, so all ranks of the same step found beside
the file are concatenated in rank order. ``splats`` holds ``means`` [N, 3], ``quats`` [N, 4] (w, x, y, z, not
normalised), ``scales`` [N, 3] (log), ``opacities`` [N] (logits), and ``sh0`` [N, 1, 3] with ``shN`` [N, K-1, 3] --
or, with the appearance model, ``colors`` [N, 3] (logits of RGB; its per-view ``features`` are dropped, logged).

**nerfstudio splatfacto** saves ``{"step", "pipeline": state_dict, "optimizers", ...}``; the Gaussians are
``pipeline["_model.gauss_params.<name>"]`` (older releases: ``_model.<name>``; a DDP run adds ``module.``, which is
removed): ``means``, ``quats`` (w, x, y, z), ``scales`` (log), ``opacities`` [N, 1] (logits), ``features_dc`` [N, 3]
and ``features_rest`` [N, K-1, 3]. With SH degree 0 (no ``features_rest`` coefficients) ``features_dc`` is the logit
of the RGB colour (splatfacto renders ``sigmoid(features_dc)``), converted here to the SH DC term.

Checkpoints are read with ``torch.load(weights_only=True)`` only: a file that needs more (pickled code) is refused.

**The metric frame.** Both trainers train in a normalised frame ``x_n = s R x + t``:

- nerfstudio writes ``dataparser_transforms.json`` (``transform`` 3x4 [R | t], ``scale`` s, with
  ``x_n = s (R x + t)``) beside ``config.yml``, the folder above ``nerfstudio_models/``; it is found there or given;
- gsplat's COLMAP parser (``normalize_world_space``, on by default) does not save it, so it is recomputed from the
  same COLMAP model (:func:`gsplat_normalization`): a similarity from the cameras (rotate the mean camera up to -y,
  recentre on the median of the points nearest the origin on each camera's axis, scale by 1 / the median camera
  distance), then the principal axes of the transformed points (median centre, axes by decreasing variance, a
  right-handed basis), then a half turn about x when the points' median height is above their mean.

The inverse is applied with :func:`recon.similarity.transform_gaussians`; the file's values are then in the
frame of the data the trainer read (COLMAP's, or the transforms.json's).
"""

from __future__ import annotations

import json
import logging
import pickle
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from fluidsim.files import check_input_file

from ..gaussians import SH_C0, GaussianSet
from ..inflate import check_budget
from ..similarity import invert_similarity, split_similarity, transform_gaussians
from .arrays import gaussians_from_arrays

log = logging.getLogger(__name__)

GSPLAT_RANK = re.compile(r"^(?P<stem>.*_)rank(?P<rank>\d+)$")
GSPLAT_KEYS = ("means", "quats", "scales", "opacities")
NERFSTUDIO_KEYS = ("means", "quats", "scales", "opacities", "features_dc")
CHECKPOINT_SUFFIXES = (".pt", ".pth", ".ckpt")
MAX_JSON_BYTES = 1 << 20  # a dataparser_transforms.json is a few hundred bytes
NO_GAUSSIANS_FIX = (
    "pass the checkpoint that holds the trained Gaussians (gsplat: results/<run>/ckpts/ckpt_<step>_"
    "rank0.pt; nerfstudio: outputs/<run>/splatfacto/<time>/nerfstudio_models/step-<step>.ckpt), or "
    "export a .ply with the trainer"
)


@dataclass(frozen=True)
class TrainedModel:
    """Gaussians read from a trainer's checkpoint.

    Attributes:
        gaussians: the set, in the trainer's normalised frame.
        trainer: "gsplat" or "nerfstudio".
        files: the checkpoint files read (several ranks for gsplat).
    """

    gaussians: GaussianSet
    trainer: str
    files: tuple[Path, ...]


def is_torch_checkpoint(names: list[str]) -> bool:
    """Whether zip member ``names`` are those of a ``torch.save`` file (a ``<name>/data.pkl``)."""
    return any(n.endswith("/data.pkl") or n == "data.pkl" for n in names)


def load_trained_model(path: str | Path) -> TrainedModel:
    """Read the Gaussians of a gsplat or nerfstudio checkpoint (module docstring), activations kept raw
    (log-scales, opacity logits, unnormalised quaternions), in the trainer's normalised frame.

    Raises:
        ValueError: naming the file: not loadable with ``weights_only=True``, or no Gaussians in it.
    """
    path = Path(path)
    state = _torch_load(path)
    if isinstance(state, dict) and isinstance(state.get("splats"), dict):
        files = _gsplat_ranks(path)
        sets = [_gsplat_set(state if f == path else _torch_load(f), f) for f in files]
        if len(files) > 1:
            log.info("%s: %d gsplat ranks concatenated (%s)", path, len(files), ", ".join(f.name for f in files))
        return TrainedModel(_concat(sets, str(path)), "gsplat", tuple(files))
    if isinstance(state, dict) and isinstance(state.get("pipeline"), dict):
        return TrainedModel(_nerfstudio_set(state["pipeline"], path), "nerfstudio", (path,))
    keys = sorted(state)[:8] if isinstance(state, dict) else type(state).__name__
    raise ValueError(
        f"{path}: a checkpoint without Gaussians: neither gsplat's 'splats' nor nerfstudio's 'pipeline' "
        f"is in it (it holds {keys}); {NO_GAUSSIANS_FIX}"
    )


def _torch_load(path: Path):
    try:
        with zipfile.ZipFile(path) as archive:
            check_budget(str(path), "the checkpoint's tensors", sum(i.file_size for i in archive.infolist()))
    except zipfile.BadZipFile:
        check_budget(str(path), "the checkpoint", path.stat().st_size)
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, OSError, ValueError, AttributeError, TypeError) as exc:
        first = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
        raise ValueError(
            f"{path}: not a checkpoint that loads safely with torch.load(weights_only=True) ({first}); "
            f"checkpoints that need arbitrary code are refused; {NO_GAUSSIANS_FIX}"
        ) from None


def _gsplat_ranks(path: Path) -> list[Path]:
    match = GSPLAT_RANK.match(path.stem)
    if match is None:
        return [path]
    ranks = {}
    for f in path.parent.glob(f"{match['stem']}rank*{path.suffix}"):
        m = GSPLAT_RANK.match(f.stem)
        if m is not None and m["stem"] == match["stem"]:
            ranks[int(m["rank"])] = check_input_file(
                f, "the gsplat rank", f"every {match['stem']}rank*{path.suffix} beside {path.name} is read; move it"
            )
    return [ranks[r] for r in sorted(ranks)]


def _array(value, name: str, source: str) -> np.ndarray:
    if not isinstance(value, torch.Tensor):
        raise ValueError(f"{source}: {name} is not a tensor ({type(value).__name__}); {NO_GAUSSIANS_FIX}")
    if not (value.dtype.is_floating_point):
        raise ValueError(f"{source}: {name} has dtype {value.dtype}, expected floating point")
    stored = value.untyped_storage().nbytes()
    if value.numel() * value.element_size() > stored:  # a zero-stride (expand) view: tiny on disk, huge when copied
        raise ValueError(
            f"{source}: {name} declares {tuple(value.shape)} = {value.numel()} values but stores only "
            f"{stored} bytes (a zero-stride or overlapping view, as torch's expand makes): not a trained model; "
            f"{NO_GAUSSIANS_FIX}"
        )
    return value.detach().to("cpu", torch.float32).numpy()


def _gsplat_set(state, path: Path) -> GaussianSet:
    source = str(path)
    splats = state.get("splats") if isinstance(state, dict) else None
    if not isinstance(splats, dict):
        raise ValueError(f"{source}: this gsplat rank has no 'splats'; {NO_GAUSSIANS_FIX}")
    missing = [k for k in GSPLAT_KEYS if k not in splats]
    if missing:
        raise ValueError(
            f"{source}: a checkpoint without Gaussians: its 'splats' lack {missing} (it holds "
            f"{sorted(splats)}); {NO_GAUSSIANS_FIX}"
        )
    a = {k: _array(splats[k], f"splats[{k!r}]", source) for k in GSPLAT_KEYS}
    if "sh0" in splats:
        sh = _array(splats["sh0"], "splats['sh0']", source)
        if "shN" in splats:
            sh = np.concatenate([sh, _array(splats["shN"], "splats['shN']", source)], 1)
    elif "colors" in splats:
        rgb = 1.0 / (1.0 + np.exp(-_array(splats["colors"], "splats['colors']", source)))
        sh = ((rgb - 0.5) / SH_C0)[:, None, :]
        log.warning(
            "%s: trained with the appearance model: its per-view features are dropped and the base colours kept", source
        )
    else:
        raise ValueError(
            f"{source}: its 'splats' have neither 'sh0' nor 'colors' (it holds {sorted(splats)}); {NO_GAUSSIANS_FIX}"
        )
    return gaussians_from_arrays(source, a["means"], a["quats"], a["scales"], a["opacities"].reshape(-1), sh)


def _nerfstudio_set(pipeline: dict, path: Path) -> GaussianSet:
    source = str(path)
    state = {".".join(p for p in k.split(".") if p != "module"): v for k, v in pipeline.items()}
    for prefix in ("_model.gauss_params.", "_model."):
        found = {k[len(prefix) :]: v for k, v in state.items() if k.startswith(prefix)}
        if all(k in found for k in NERFSTUDIO_KEYS):
            break
    else:
        model_keys = sorted(k for k in state if k.startswith("_model."))[:8]
        raise ValueError(
            f"{source}: a checkpoint without Gaussians: its pipeline has no splatfacto Gaussians "
            f"('_model.gauss_params.means' and the like; model keys: {model_keys or 'none'}); "
            f"{NO_GAUSSIANS_FIX}"
        )
    a = {k: _array(found[k], f"pipeline['{prefix}{k}']", source) for k in NERFSTUDIO_KEYS}
    n = a["means"].shape[0]
    dc = a["features_dc"].reshape(n, 3)
    rest = (
        _array(found["features_rest"], f"pipeline['{prefix}features_rest']", source)
        if "features_rest" in found
        else np.zeros((n, 0, 3), np.float32)
    )
    if rest.shape[1] == 0:  # SH degree 0: features_dc is the logit of the colour
        dc = (1.0 / (1.0 + np.exp(-dc)) - 0.5) / SH_C0
    sh = np.concatenate([dc[:, None, :], rest], 1)
    return gaussians_from_arrays(source, a["means"], a["quats"], a["scales"], a["opacities"].reshape(-1), sh)


def _concat(sets: list[GaussianSet], source: str) -> GaussianSet:
    degrees = {g.sh_degree for g in sets}
    if len(degrees) > 1:
        raise ValueError(f"{source}: the gsplat ranks have different SH degrees {sorted(degrees)}")
    return GaussianSet(*(torch.cat(parts) for parts in zip(*(g.tensors() for g in sets), strict=True)))


# ---- the metric frame ------------------------------------------------------------------------------------------
def find_dataparser_transforms(checkpoint: Path) -> Path | None:
    """``dataparser_transforms.json`` beside the checkpoint or beside its ``config.yml`` (the folder above
    ``nerfstudio_models/``), else None."""
    for folder in (checkpoint.parent, checkpoint.parent.parent):
        candidate = folder / "dataparser_transforms.json"
        if candidate.is_file():
            return candidate
    return None


def nerfstudio_normalization(path: Path) -> np.ndarray:
    """The 4x4 similarity data -> nerfstudio frame of a ``dataparser_transforms.json``: ``s [R | t]``."""
    check_input_file(path, "--dataparser-transforms", "pass the dataparser_transforms.json beside config.yml")
    if Path(path).stat().st_size > MAX_JSON_BYTES:
        raise ValueError(f"{path}: {Path(path).stat().st_size} bytes, not a dataparser_transforms.json; pass that file")
    try:
        doc = json.loads(Path(path).read_text())
        transform = np.asarray(doc["transform"], np.float64)
        scale = float(doc["scale"])
    except (OSError, ValueError, KeyError, TypeError, RecursionError) as exc:
        raise ValueError(
            f"{path}: not a nerfstudio dataparser_transforms.json with 'transform' (3x4) and 'scale' "
            f"({exc}); pass the one written beside the run's config.yml"
        ) from None
    if transform.shape != (3, 4) or not np.isfinite(transform).all() or not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"{path}: 'transform' must be a finite 3x4 matrix and 'scale' a positive number")
    matrix = np.eye(4)
    matrix[:3] = scale * transform
    return matrix


def gsplat_normalization(camtoworlds: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The 4x4 similarity COLMAP -> gsplat frame that gsplat's COLMAP parser applies (module docstring).

    Args:
        camtoworlds: [C, 4, 4] camera-to-world matrices of every image of the model (OpenCV axes).
        points: [P, 3] the model's 3D points.
    """
    c2w = np.asarray(camtoworlds, np.float64)
    pts = np.asarray(points, np.float64)
    t1 = _similarity_from_cameras(c2w)
    c2w = _transform_cameras(t1, c2w)
    pts = pts @ t1[:3, :3].T + t1[:3, 3]
    t2 = _principal_axes(pts)
    pts = pts @ t2[:3, :3].T + t2[:3, 3]
    transform = t2 @ t1
    if np.median(pts[:, 2]) > np.mean(pts[:, 2]):
        transform = np.diag([1.0, -1.0, -1.0, 1.0]) @ transform
    return transform


def _similarity_from_cameras(c2w: np.ndarray) -> np.ndarray:
    rotations, centres = c2w[:, :3, :3], c2w[:, :3, 3]
    up = -rotations[:, :, 1].mean(0)  # the cameras' mean up (image -y) in the world
    up /= np.linalg.norm(up)
    target = np.array([0.0, -1.0, 0.0])  # gsplat aligns the mean up with the camera-space up, -y
    # the rotation taking the mean up to -y (Rodrigues about up x target); gsplat's own matrix when up is +y
    c = float(up @ target)
    if c > -1.0:
        v = np.cross(up, target)
        vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
        align = np.eye(3) + vx + vx @ vx / (1.0 + c)
    else:
        align = np.diag([-1.0, 1.0, 1.0])
    rotations = align @ rotations
    forwards = rotations[:, :, 2]
    centres = centres @ align.T
    nearest = centres + ((-centres * forwards).sum(1))[:, None] * forwards
    translate = -np.median(nearest, axis=0)
    scale = 1.0 / np.median(np.linalg.norm(centres + translate, axis=1))
    out = np.eye(4)
    out[:3, :3] = scale * align
    out[:3, 3] = scale * translate
    return out


def _transform_cameras(matrix: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    out = matrix[None] @ c2w
    out[:, :3, :3] /= np.linalg.norm(out[:, :3, 0], axis=1)[:, None, None]
    return out


def _principal_axes(points: np.ndarray) -> np.ndarray:
    centre = np.median(points, axis=0)
    values, vectors = np.linalg.eigh(np.cov(points - centre, rowvar=False))
    vectors = vectors[:, np.argsort(values)[::-1]]
    if np.linalg.det(vectors) < 0:
        vectors[:, 0] *= -1
    out = np.eye(4)
    out[:3, :3] = vectors.T
    out[:3, 3] = -vectors.T @ centre
    return out


def colmap_normalization(folder: Path) -> np.ndarray:
    """:func:`gsplat_normalization` of the COLMAP model in ``folder`` (``sparse/0``, ``sparse`` or the model)."""
    from ..colmap import find_colmap_sparse, read_colmap_model  # noqa: PLC0415 - only gsplat restores need it

    sparse = find_colmap_sparse(Path(folder))
    if sparse is None:
        raise ValueError(
            f"--colmap {folder}: no COLMAP model (cameras, images and points3D .bin or .txt) in it, in "
            f"sparse/0 or in sparse; pass the model gsplat was trained on"
        )
    model = read_colmap_model(sparse)
    if not model.images or len(model.points) < 4:
        raise ValueError(
            f"--colmap {sparse}: {len(model.images)} images and {len(model.points)} points; gsplat's "
            f"normalisation needs the cameras and the points of the model it was trained on"
        )
    camtoworlds = np.linalg.inv(np.stack([w2c for _, w2c, _, _ in model.images]))
    try:
        with np.errstate(divide="ignore", invalid="ignore"):  # cameras in one place: a scale of 1/0
            return gsplat_normalization(camtoworlds, model.points)
    except np.linalg.LinAlgError as exc:
        raise ValueError(
            f"--colmap {sparse}: gsplat's normalisation of it is undefined ({exc}: the cameras stand in one place); "
            "pass the COLMAP model gsplat was trained on"
        ) from None


def _undone(normalization: np.ndarray, what: str, fix: str) -> np.ndarray:
    """The inverse of a trainer's normalisation, or a ValueError naming where it came from (``what``) and ``fix``:
    a degenerate one (a scale that overflows or vanishes, cameras all in one place) is no similarity."""
    try:
        split_similarity(normalization, what)
    except ValueError as exc:
        raise ValueError(f"{exc}; pass {fix}") from None
    return invert_similarity(normalization)


def restore_metric_frame(
    model: TrainedModel, colmap: Path | None = None, dataparser_transforms: Path | None = None
) -> tuple[GaussianSet, np.ndarray | None, str]:
    """Undo the trainer's normalisation when its transform is known.

    Returns:
        (the Gaussians, the 4x4 normalised -> restored matrix applied or None, a one-line description). When the
        frame cannot be restored the Gaussians are returned as they are, and the description (also logged as a
        warning) says that sizes are in the trainer's normalised units and how to fix it.
    """
    path = model.files[0]
    if model.trainer == "nerfstudio":
        found = dataparser_transforms or find_dataparser_transforms(path)
        if found is not None:
            undo = _undone(
                nerfstudio_normalization(found),
                f"{found}: 'scale' times 'transform'",
                "the one written beside the run's config.yml",
            )
            return (transform_gaussians(model.gaussians, undo), undo, f"nerfstudio's normalisation undone with {found}")
        fix = "pass --dataparser-transforms PATH (written beside the run's config.yml)"
    else:
        if colmap is not None:
            undo = _undone(
                colmap_normalization(colmap),
                f"--colmap {colmap}: gsplat's normalisation of it",
                "the COLMAP model gsplat was trained on",
            )
            return (
                transform_gaussians(model.gaussians, undo),
                undo,
                f"gsplat's COLMAP normalisation recomputed from {colmap} and undone",
            )
        fix = "pass --colmap DIR, the COLMAP model gsplat was trained on (sparse/0 or its parent)"
    note = (
        f"{path}: the {model.trainer} checkpoint is in the trainer's normalised frame: sizes are in its normalised "
        f"units, not the capture's, so the fluid sees the object at the wrong size; {fix}"
    )
    log.warning("%s", note)
    return model.gaussians, None, note
