"""Reading and writing Gaussian sets as the standard 3DGS ``.ply`` (writing also a plain ``.npz``, :mod:`.npz`).

The ``.ply`` layout is the one of the reference 3DGS trainer (Kerbl et al. 2023, ``GaussianModel.save_ply``), so
files move both ways between this project and the common viewers and trainers. One ``vertex`` element holds,
in this order, one float32 property each::

    x y z  nx ny nz  f_dc_0 f_dc_1 f_dc_2  f_rest_0 .. f_rest_{3(K-1)-1}  opacity  scale_0 scale_1 scale_2
    rot_0 rot_1 rot_2 rot_3

Stored values are the raw parameters of :class:`~recon.gaussians.GaussianSet`: ``opacity`` is the logit,
``scale_*`` the natural log of the standard deviations, ``rot_*`` the (w, x, y, z) quaternion (not necessarily
normalised) and ``f_dc_*`` the DC SH coefficient per colour channel. Normals are written as 0 and ignored on
reading. ``f_rest`` is channel-major: ``f_rest[c * (K - 1) + j]`` is SH coefficient ``j + 1`` of colour
channel ``c`` (the reference trainer keeps the higher bands as [N, K-1, 3], transposes them to [N, 3, K-1] and
flattens). The SH degree is read from the number of ``f_rest`` properties: 0, 9, 24 or 45 for degrees 0-3.

Reading accepts ``format binary_little_endian 1.0``, ``binary_big_endian 1.0`` and ``ascii 1.0``; scalar
properties of any PLY type (char, uchar, short, ushort, int, uint, float, double, and their sized aliases),
converted to float32; extra vertex properties are ignored, and so are elements after ``vertex``. Writing is
always binary little-endian float32, atomically (:func:`fluidsim.files.write_bytes_atomic`).

Every problem (not a PLY, unsupported format, missing properties, unsupported f_rest count, truncated data,
NaN or Inf, zero quaternions, no Gaussians) raises ``ValueError`` whose message starts with the file name.
Declared PLY element rows are compared with the file size before anything is allocated.

This is the low-level module: :func:`load_standard_ply` reads one layout. The loader to call is
:func:`recon.formats.load_gaussians`, which recognises a file by its content (also the compressed .ply, .spz and
.splat formats of :mod:`recon.formats.compressed_ply`, :mod:`recon.formats.spz` and :mod:`recon.formats.dotsplat`).

Example:
    >>> g = GaussianSet.from_points(torch.rand(10, 3), sh_degree=3)
    >>> save_gaussians(g, "point_cloud.ply")  # doctest: +SKIP
    >>> load_gaussians("point_cloud.ply").sh.shape  # doctest: +SKIP
    torch.Size([10, 16, 3])
"""

from __future__ import annotations

import io
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from fluidsim.files import write_bytes_atomic

from ..gaussians import GaussianSet, sh_coefficient_count
from .arrays import check_declared_size
from .npz import NPZ_KEYS

PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
PLY_FORMATS = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": None}
REQUIRED_PROPERTIES = (
    "x",
    "y",
    "z",
    "f_dc_0",
    "f_dc_1",
    "f_dc_2",
    "opacity",
    "scale_0",
    "scale_1",
    "scale_2",
    "rot_0",
    "rot_1",
    "rot_2",
    "rot_3",
)
F_REST_COUNTS = {0: 0, 9: 1, 24: 2, 45: 3}  # number of f_rest properties -> SH degree
MAX_HEADER_LINES = 10_000
MAX_HEADER_LINE_BYTES = 4096


def ply_property_names(sh_degree: int) -> list[str]:
    """The vertex property names of a 3DGS ``.ply`` of SH degree ``sh_degree``, in the reference order."""
    rest = 3 * (sh_coefficient_count(sh_degree) - 1)
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


@dataclass(frozen=True)
class PlyElement:
    """One ``element`` of a PLY header.

    Attributes:
        name: the element name (``vertex``, ``chunk``, ``sh``, ``face``, ...).
        count: number of rows the header declares.
        properties: (name, numpy type code such as "f4", or "list") of each property, in file order.
    """

    name: str
    count: int
    properties: tuple[tuple[str, str], ...]

    def row_bytes(self) -> int | None:
        """Bytes per row in a binary file, or None when a list property makes rows variable."""
        if any(t == "list" for _, t in self.properties):
            return None
        return sum(np.dtype(t).itemsize for _, t in self.properties)


@dataclass(frozen=True)
class PlyLayout:
    """Everything a PLY header says: the format, the elements in file order and where the data starts."""

    fmt: str
    elements: tuple[PlyElement, ...]
    data_offset: int

    def element(self, name: str) -> PlyElement | None:
        """The first element called ``name``, or None."""
        return next((e for e in self.elements if e.name == name), None)


@dataclass(frozen=True)
class PlyHeader:
    """The parts of a PLY header the loader needs.

    Attributes:
        fmt: "ascii", "binary_little_endian" or "binary_big_endian".
        vertex_count: number of rows of the ``vertex`` element.
        properties: (name, numpy type code such as "f4") of each vertex property, in file order.
        data_offset: byte offset of the first data byte (just after ``end_header``).
    """

    fmt: str
    vertex_count: int
    properties: tuple[tuple[str, str], ...]
    data_offset: int


def parse_ply_header(fh, source: str) -> PlyLayout:
    """Parse a whole PLY header (any elements) of an open binary file ``fh`` positioned at its start.

    Args:
        fh: file object opened in binary mode.
        source: the file name, used in error messages.
    Returns:
        The :class:`PlyLayout`; ``fh`` is left just after ``end_header``.
    Raises:
        ValueError: not a PLY file, an unsupported format line, malformed element or property lines, or no
            ``end_header``.
    """
    magic = fh.readline(64)
    if magic.rstrip(b"\r\n") != b"ply":
        raise ValueError(f"{source}: not a PLY file (the first line is {magic[:20]!r}, expected 'ply')")
    fmt = None
    elements: list[list] = []  # [name, count, [(prop, type)]]
    for _ in range(MAX_HEADER_LINES):
        start = fh.tell()
        raw = fh.readline(MAX_HEADER_LINE_BYTES)
        if not raw:
            raise ValueError(f"{source}: the PLY header has no 'end_header' line (truncated file)")
        if len(raw) >= MAX_HEADER_LINE_BYTES and not raw.endswith(b"\n"):
            raise ValueError(
                f"{source}: the PLY header has no 'end_header' line within its first {fh.tell():,} bytes: the line "
                f"at byte {start:,} runs past {MAX_HEADER_LINE_BYTES:,} bytes, so data follows where the header "
                "should have ended; the header is truncated or damaged (a PLY header ends with 'end_header')"
            )
        try:
            words = raw.decode("ascii").split()
        except UnicodeDecodeError as exc:
            raise ValueError(
                f"{source}: the PLY header has no 'end_header' line before the non-ASCII bytes at byte {start:,} "
                f"({exc.reason}); the header is truncated or damaged (a PLY header ends with 'end_header')"
            ) from None
        if not words or words[0] in ("comment", "obj_info"):
            continue
        key = words[0]
        if key == "end_header":
            break
        if key == "format":
            if len(words) != 3 or words[1] not in PLY_FORMATS or words[2] != "1.0":
                raise ValueError(
                    f"{source}: unsupported PLY format line {' '.join(words)!r}; expected "
                    f"'format ascii|binary_little_endian|binary_big_endian 1.0'"
                )
            fmt = words[1]
        elif key == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise ValueError(f"{source}: malformed PLY element line {' '.join(words)!r}")
            elements.append([words[1], int(words[2]), []])
        elif key == "property":
            if not elements:
                raise ValueError(f"{source}: PLY property {' '.join(words)!r} before any element")
            if len(words) >= 2 and words[1] == "list":
                elements[-1][2].append((words[-1], "list"))
            elif len(words) == 3 and words[1] in PLY_TYPES:
                elements[-1][2].append((words[2], PLY_TYPES[words[1]]))
            else:
                raise ValueError(f"{source}: unsupported PLY property line {' '.join(words)!r}")
        else:
            raise ValueError(f"{source}: unknown PLY header keyword {key!r}")
    else:
        raise ValueError(
            f"{source}: the PLY header has no 'end_header' line within its first {MAX_HEADER_LINES:,} lines "
            f"({fh.tell():,} bytes); the header is truncated or damaged (a PLY header ends with 'end_header')"
        )
    if fmt is None:
        raise ValueError(f"{source}: the PLY header has no 'format' line")
    return PlyLayout(fmt, tuple(PlyElement(n, c, tuple(p)) for n, c, p in elements), fh.tell())


def read_ply_header(fh, source: str) -> PlyHeader:
    """Parse the header of a standard 3DGS PLY (``vertex`` first) of an open binary file ``fh``.

    Args:
        fh: file object opened in binary mode, positioned at its start.
        source: the file name, used in error messages.
    Returns:
        The :class:`PlyHeader`; ``fh`` is left just after ``end_header``.
    Raises:
        ValueError: not a PLY file, an unsupported format, no ``vertex`` element, a list property in the vertex
            element, or an element with rows before ``vertex``.
    """
    layout = parse_ply_header(fh, source)
    offset = layout.data_offset
    for element in layout.elements:
        if element.name == "vertex":
            lists = [p for p, t in element.properties if t == "list"]
            if lists:
                raise ValueError(
                    f"{source}: the vertex element has list properties {lists}; a 3DGS file has scalar properties only"
                )
            return PlyHeader(layout.fmt, element.count, element.properties, offset)
        offset = _skip_element(fh, element, layout.fmt, offset, source)
    raise ValueError(f"{source}: the PLY file has no 'vertex' element, so it holds no Gaussians")


def _skip_element(fh, element: PlyElement, fmt: str, offset: int, source: str) -> int:
    """Move ``fh`` past the rows of an element that comes before ``vertex`` (a camera, a chunk table, ...).

    Binary rows must have a fixed size (their bytes are checked against the file size before seeking); ASCII
    rows are one line each. Returns the new byte offset.
    """
    if element.count == 0:
        return offset
    row = element.row_bytes()
    if PLY_FORMATS[fmt] is not None:
        if row is None:
            raise ValueError(
                f"{source}: element {element.name!r} ({element.count} rows) comes before 'vertex' and "
                f"has list properties, so the vertex data cannot be located; re-export the file with "
                f"the vertex element first"
            )
        size = element.count * row
        check_declared_size(
            source,
            f"{element.count} {element.name!r} rows before the vertices",
            size,
            os.fstat(fh.fileno()).st_size - offset,
        )
        fh.seek(offset + size)
        return offset + size
    for _ in range(element.count):
        if not fh.readline():
            raise ValueError(f"{source}: truncated PLY data inside element {element.name!r} (before 'vertex')")
    return fh.tell()


def read_binary_elements(path: str | Path, names: tuple[str, ...]) -> tuple[PlyLayout, dict[str, np.ndarray]]:
    """The rows of the binary PLY elements ``names`` as structured numpy arrays, in one pass over the file.

    Every element before the last one asked for must have fixed-size rows (scalar properties only), so the
    offsets are known. The declared sizes are compared with the file size before anything is allocated.

    Args:
        path: a binary (little- or big-endian) PLY file.
        names: the elements to return; each must be present.
    Returns:
        (layout, {name: structured array [count]}) with the file's own property types.
    Raises:
        ValueError: an ASCII file, a missing element, a list property in the way, or truncated data.
    """
    source = str(path)
    with open(path, "rb") as fh:
        layout = parse_ply_header(fh, source)
        order = PLY_FORMATS[layout.fmt]
        if order is None:
            raise ValueError(f"{source}: ASCII PLY is not supported for this layout; export it as binary")
        missing = [n for n in names if layout.element(n) is None]
        if missing:
            raise ValueError(f"{source}: the PLY file has no element(s) {missing}")
        last = max(i for i, e in enumerate(layout.elements) if e.name in names)
        sizes = []
        for element in layout.elements[: last + 1]:
            row = element.row_bytes()
            if row is None:
                raise ValueError(f"{source}: element {element.name!r} has list properties; expected fixed-size rows")
            sizes.append(element.count * row)
        available = os.fstat(fh.fileno()).st_size - layout.data_offset
        what = ", ".join(f"{e.count} {e.name} rows" for e in layout.elements[: last + 1])
        check_declared_size(source, what, sum(sizes), available)
        out = {}
        offset = layout.data_offset
        for element, size in zip(layout.elements[: last + 1], sizes, strict=True):
            if element.name in names:
                dtype = np.dtype([(p, order + t) for p, t in element.properties])
                fh.seek(offset)
                out[element.name] = np.fromfile(fh, dtype=dtype, count=element.count)
            offset += size
    return layout, out


def read_ply_vertices(path: str | Path) -> dict[str, np.ndarray]:
    """All vertex properties of a PLY file as float32 arrays [N], keyed by property name.

    Args:
        path: a ``.ply`` file (ascii or binary, any scalar property types).
    Returns:
        ``{name: array [N]}`` in file order.
    Raises:
        ValueError: malformed header or truncated data (the message names the file).
    """
    source = str(path)
    with open(path, "rb") as fh:
        header = read_ply_header(fh, source)
        names = [p for p, _ in header.properties]
        duplicates = sorted({p for p in names if names.count(p) > 1})
        if duplicates:
            raise ValueError(f"{source}: duplicate vertex properties {duplicates}")
        n = header.vertex_count
        order = PLY_FORMATS[header.fmt]
        if order is None:
            return _read_ascii_vertices(fh, header, source)
        types = {t for _, t in header.properties}
        # One scalar type (every trainer's float32 file): the rows read as one table whose columns are views.
        record = np.dtype(order + types.pop()) if len(types) == 1 else None
        dtype = np.dtype([(p, order + t) for p, t in header.properties])
        available = os.fstat(fh.fileno()).st_size - header.data_offset
        check_declared_size(source, f"{n} vertices of {dtype.itemsize} bytes", n * dtype.itemsize, available)
        if record is not None:
            data = np.fromfile(fh, dtype=record, count=n * len(names)) if n > 0 else np.zeros(0, record)
            present = data.size // len(names)
        else:
            data = np.fromfile(fh, dtype=dtype, count=n) if n > 0 else np.zeros(0, dtype)
            present = data.shape[0]
    if present != n:
        raise ValueError(
            f"{source}: truncated PLY data: the header declares {n} vertices of {dtype.itemsize} bytes "
            f"but only {present} are present"
        )
    if record is not None:
        table = data.reshape(n, len(names))
        return {p: table[:, i].astype(np.float32, copy=False) for i, p in enumerate(names)}
    return {p: data[p].astype(np.float32) for p in names}


def _read_ascii_vertices(fh, header: PlyHeader, source: str) -> dict[str, np.ndarray]:
    n, m = header.vertex_count, len(header.properties)
    tokens = fh.read().split()
    if len(tokens) < n * m:
        raise ValueError(
            f"{source}: truncated PLY data: the header declares {n} vertices of {m} values "
            f"but only {len(tokens)} values are present"
        )
    try:
        table = np.array(tokens[: n * m], dtype=np.float64).reshape(n, m)
    except ValueError as exc:
        raise ValueError(f"{source}: non-numeric value in the ASCII vertex data ({exc})") from None
    return {p: table[:, i].astype(np.float32) for i, (p, _) in enumerate(header.properties)}


def gaussians_from_ply_columns(columns: dict[str, np.ndarray], source: str) -> GaussianSet:
    """Assemble a :class:`GaussianSet` from 3DGS vertex columns (see the module docstring for the layout).

    Raises:
        ValueError: missing required properties, or an ``f_rest`` count other than 0, 9, 24 or 45.
    """
    missing = [p for p in REQUIRED_PROPERTIES if p not in columns]
    if missing:
        raise ValueError(
            f"{source}: not a 3DGS Gaussian file: vertex properties {missing} are missing "
            f"(a plain point cloud .ply has only x, y, z and colours); export the trained Gaussians "
            f"with the 3DGS layout"
        )
    rest_names = sorted((p for p in columns if re.fullmatch(r"f_rest_\d+", p)), key=lambda p: int(p[7:]))
    if len(rest_names) not in F_REST_COUNTS:
        raise ValueError(
            f"{source}: {len(rest_names)} f_rest properties; a 3DGS file has 0, 9, 24 or 45 (SH degree 0, 1, 2 or 3)"
        )
    expected = [f"f_rest_{i}" for i in range(len(rest_names))]
    if rest_names != expected:
        raise ValueError(f"{source}: f_rest properties are not numbered f_rest_0..f_rest_{len(rest_names) - 1}")
    n = columns["x"].shape[0]
    k = sh_coefficient_count(F_REST_COUNTS[len(rest_names)])

    def stack(names: list[str]) -> torch.Tensor:
        if not names:
            return torch.zeros(n, 0)
        return torch.from_numpy(np.stack([columns[p] for p in names], 1).astype(np.float32, copy=False))

    dc = stack(["f_dc_0", "f_dc_1", "f_dc_2"])
    rest = stack(rest_names).reshape(n, 3, k - 1).transpose(1, 2)  # channel-major -> [N, K-1, 3]
    gaussians = GaussianSet(
        means=stack(["x", "y", "z"]),
        quats=stack(["rot_0", "rot_1", "rot_2", "rot_3"]),
        log_scales=stack(["scale_0", "scale_1", "scale_2"]),
        opacity_logits=stack(["opacity"])[:, 0].contiguous(),
        sh=torch.cat([dc[:, None, :], rest], 1).contiguous(),
    )
    return gaussians.check(source)


def load_standard_ply(path: str | Path) -> GaussianSet:
    """Read Gaussians from a standard 3DGS ``.ply`` (layout in the module docstring).

    Args:
        path: the file (any suffix; the content must be a PLY with a 3DGS ``vertex`` element).
    Returns:
        A float32 :class:`GaussianSet` on the CPU; the SH degree follows the file (0 to 3).
    Raises:
        ValueError: any problem with the content; the message starts with the file name.
    """
    return gaussians_from_ply_columns(read_ply_vertices(path), str(path))


def save_gaussians(gaussians: GaussianSet, path: str | Path, extra: dict[str, np.ndarray] | None = None) -> Path:
    """Write ``gaussians`` as a 3DGS ``.ply`` (binary little-endian float32) or an ``.npz``, atomically.

    The set is checked first (:meth:`GaussianSet.check`), so a file this function writes always loads again.
    Parent folders are created. Values are converted to float32 on the CPU.

    Args:
        gaussians: the set (any device or dtype; gradients are ignored).
        path: destination; the suffix ``.ply`` or ``.npz`` picks the layout.
        extra: .ply only: further float32 vertex properties after the standard ones, ``{name: [N] values}``, in
            order (names of letters, digits and ``_``, none a standard name); 3DGS viewers and converters such as
            SuperSplat and splat-transform keep them as extra columns, and our reader ignores them.
    Returns:
        The written path.
    Raises:
        ValueError: an unsupported suffix, or an empty / non-finite set or a zero quaternion (nothing is written).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".ply", ".npz"):
        raise ValueError(f"{path}: unsupported Gaussian file type {path.suffix!r}; use .ply or .npz")
    g = gaussians.detach().to(device="cpu", dtype=torch.float32)
    g.check(str(path))
    columns = _extra_columns(extra or {}, g, path)
    if columns and suffix != ".ply":
        raise ValueError(f"{path}: extra vertex properties need a .ply, not {path.suffix!r}")
    if suffix == ".ply":
        payload = _ply_bytes(g, columns)
    else:
        buffer = io.BytesIO()
        np.savez(buffer, **{name: t.numpy() for name, t in zip(NPZ_KEYS, g.tensors(), strict=True)})
        payload = buffer.getvalue()
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_bytes_atomic(path, payload)


def _extra_columns(extra: dict[str, np.ndarray], g: GaussianSet, path: Path) -> dict[str, np.ndarray]:
    """The extra vertex properties checked: names, shapes [N], finite values."""
    standard = set(ply_property_names(g.sh_degree))
    out = {}
    for name, values in extra.items():
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name) or name in standard:
            raise ValueError(
                f"{path}: extra vertex property name {name!r} must be letters, digits and _ and not a "
                "standard 3DGS property"
            )
        v = np.asarray(values, dtype=np.float32).reshape(-1)
        if v.shape != (g.num,):
            raise ValueError(f"{path}: extra vertex property {name!r} has {v.size} values for {g.num} Gaussians")
        if not np.isfinite(v).all():
            raise ValueError(f"{path}: extra vertex property {name!r} holds NaN or inf")
        out[name] = v
    return out


def _ply_bytes(g: GaussianSet, extra: dict[str, np.ndarray] | None = None) -> bytes:
    extra = extra or {}
    names = ply_property_names(g.sh_degree) + list(extra)
    n, k = g.num, g.sh.shape[1]
    rest = g.sh[:, 1:].transpose(1, 2).reshape(n, 3 * (k - 1))  # [N, K-1, 3] -> channel-major [N, 3(K-1)]
    table = torch.cat(
        [
            g.means,
            torch.zeros(n, 3),
            g.sh[:, 0],
            rest,
            g.opacity_logits[:, None],
            g.log_scales,
            g.quats,
            *(torch.from_numpy(v)[:, None] for v in extra.values()),
        ],
        1,
    ).numpy()
    header = "".join(
        [
            "ply\n",
            "format binary_little_endian 1.0\n",
            f"element vertex {n}\n",
            *(f"property float {p}\n" for p in names),
            "end_header\n",
        ]
    )
    return header.encode("ascii") + np.ascontiguousarray(table, dtype="<f4").tobytes()
