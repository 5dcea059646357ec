"""Command-line options generated from the config dataclasses: each default is written once, in the dataclass.

A config class documents its fields in a Google-style ``Attributes:`` section (``name: what it is, unit``). From
``dataclasses.fields`` and that section, :func:`add_config_options` makes one option per field, with the field's
text as help and its default (and any preset's value) appended, so ``--help`` shows the unit and the default
without writing either in argparse; :func:`config_from_args` builds the config back from the parsed namespace,
taking only the options the user gave (the dataclass, then a preset, supply the rest).

Example::

    add_config_options(parser, PhysicsConfig, ("dt", "speed"), presets={"--quick": QUICK})
    config = config_from_args(PhysicsConfig, parser.parse_args(), ("dt", "speed"),
                              preset=QUICK if quick else None)

``--dt`` then reads "time step, s (default: 0.002)". Options default to None in argparse ("not given"), which
is how a preset can change a default without the option forgetting that the user typed it.

Per-field ``overrides`` (keys of :class:`argparse.ArgumentParser.add_argument` plus ``flags``, ``default_text``,
``convert`` and ``negate``) keep the command line's established names: ``--no-fill`` for ``fill_cavities``,
``--probe-steps`` for ``steps``. :func:`parse_list` (re-exported from :mod:`nbv.lists`), :func:`index_list` and
:func:`float_list` are the one comma-list parser of the commands.

Why not tyro: it would derive flags, types and help from the same dataclasses, but it builds the parser itself, so
the established names (``--no-fill``, ``--up-axis``, ``--probe-steps``), comma lists (tyro makes tuples
space-separated ``nargs``), presets applied under explicit values, and the nested ``fluidgs COMMAND`` parsers
with their own positional arguments would each need tyro's markers or a second parser. The generator here
(:func:`field_docs` to :func:`config_from_args`) is about 150 lines over the standard library and changes no option.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import re
import typing
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["add_camera_arguments", "add_config_options", "add_frame_arguments", "add_physics_arguments",
           "add_record_arguments", "add_runtime_arguments", "check_output_file", "config_from_args", "config_values",
           "dataset_inputs", "field_docs", "float_list", "help_and_default", "index_list", "load_gaussians_checked",
           "option_dest", "parse_list", "physics_config_from_args", "probe_overrides", "record_config_from_args",
           "save_diverged", "up_from_args"]

_ENTRY = re.compile(r"^(\s*)([A-Za-z_][\w, ]*?):\s*(.*)$")


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """``{field: text}`` from the ``Attributes:`` sections of ``cls`` and its bases (``a, b: text`` documents
    both; continuation lines are joined). Fields without an entry are missing from the result."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        docs.update(_attribute_section(klass.__doc__ or ""))
    return docs


def _attribute_section(doc: str) -> dict[str, str]:
    out: dict[str, str] = {}
    lines = doc.expandtabs().splitlines()
    start = next((i for i, line in enumerate(lines) if line.strip() == "Attributes:"), None)
    if start is None:
        return out
    names: list[str] = []
    indent = None
    for line in lines[start + 1:]:
        if not line.strip():
            continue
        depth = len(line) - len(line.lstrip())
        match = _ENTRY.match(line)
        if indent is None:
            indent = depth
        if depth < indent:
            break  # the section ended
        if depth == indent and match:
            names = [n.strip() for n in match.group(2).split(",")]
            for n in names:
                out[n] = match.group(3).strip()
        elif depth > indent and names:
            for n in names:
                out[n] = f"{out[n]} {line.strip()}"
    return out


_ROLE = re.compile(r":\w+:`~?([^`]+)`")
_NONE_CLAUSE = re.compile(r"\s*[(;,]\s*None:\s*([^)]*?)\)?\.?$")


def plain(text: str) -> str:
    """A docstring fragment as help text: Sphinx roles and double back-quotes dropped, the end's period dropped."""
    return _ROLE.sub(r"\1", text).replace("``", "").strip().rstrip(".")


def help_and_default(text: str, default: Any) -> tuple[str, str]:
    """(help, default text) of a field: a trailing "(None: what happens)" clause of a field whose default is None
    becomes the default text ("(None: the available memory)" -> "default: the available memory")."""
    text = plain(text)
    match = _NONE_CLAUSE.search(text) if default is None else None
    if match:
        return text[:match.start()].rstrip(" ,;"), match.group(1).strip().rstrip(".")
    return text, format_value(default)


def option_dest(name: str, override: Mapping[str, Any] | None = None) -> str:
    """The namespace attribute of field ``name``'s option (``override["dest"]``, else the field name)."""
    return (override or {}).get("dest", name)


def _fields(cls: type) -> dict[str, dataclasses.Field]:
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    return {f.name: f for f in dataclasses.fields(cls)}


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def _scalar_type(cls: type, name: str) -> type | None:
    """int, float or bool when the field's annotation is that (or that | None); None for anything else."""
    try:
        hint = typing.get_type_hints(cls)[name]
    except Exception:  # noqa: BLE001 - an annotation that does not evaluate here is treated as text
        return None
    args = [a for a in typing.get_args(hint) if a is not type(None)] if typing.get_args(hint) else [hint]
    return args[0] if len(args) == 1 and args[0] in (int, float, bool) else None


def format_value(value: Any) -> str:
    """A default as ``--help`` shows it: tuples as comma lists, None as "none"."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, (tuple, list)):
        return ",".join(format_value(v) for v in value)
    return str(value)


def add_config_options(parser, cls: type, fields: Sequence[str], overrides: Mapping[str, Mapping] | None = None,
                       presets: Mapping[str, Mapping[str, Any]] | None = None) -> list[argparse.Action]:
    """Add one option per field of the dataclass ``cls`` to ``parser`` (a parser or an argument group).

    Args:
        fields: the field names, in option order.
        overrides: per field, :meth:`~argparse.ArgumentParser.add_argument` keywords (``help``, ``metavar``,
            ``type``, ``choices``, ``dest``) and ``flags`` (the option strings; default ``--field-name``),
            ``default_text`` (what "(default: ...)" says, when the value alone would not say it), ``negate`` (a
            bool flag that sets the field to False, e.g. ``--no-fill``) and ``convert`` (text -> field value, for
            :func:`config_from_args`).
        presets: ``{label: {field: value}}``: a preset's value is shown next to the default ("0.05 with --quick").
    Returns:
        the added actions. A field without help (no override, no docstring entry) is a TypeError: the config's
        docstring must document it.
    """
    known, docs = _fields(cls), field_docs(cls)
    actions = []
    for name in fields:
        if name not in known:
            raise TypeError(f"{cls.__name__} has no field {name!r}")
        over = dict((overrides or {}).get(name, {}))
        flags = over.pop("flags", ("--" + name.replace("_", "-"),))
        text = over.pop("help", None)
        if text is None and not docs.get(name):
            raise TypeError(f"{cls.__name__}.{name} has no help: document it in the class's Attributes section")
        default = _default(known[name])
        doc_help, doc_default = help_and_default(docs.get(name, ""), default)
        text = doc_help if text is None else text
        shown = over.pop("default_text", None) or doc_default
        extra = [f"{format_value(p[name])} with {label}" for label, p in (presets or {}).items() if name in p]
        kind = _scalar_type(cls, name)
        negate = over.pop("negate", False)
        over.pop("convert", None)
        if kind is bool or negate:
            over.setdefault("action", "store_true")
        elif "type" not in over and kind in (int, float):
            over["type"] = kind
        over.setdefault("dest", name)
        if over.get("action") != "store_true" and "choices" not in over:  # the metavar argparse derives from a flag
            long = next((f for f in flags if f.startswith("--")), flags[0])
            over.setdefault("metavar", long.lstrip("-").replace("-", "_").upper())
        default_note = f"default: {shown}" + "".join(f"; {e}" for e in extra)
        actions.append(parser.add_argument(*flags, default=None if over.get("action") != "store_true" else False,
                                           help=f"{text} ({default_note})", **over))
    return actions


def config_values(cls: type, args: argparse.Namespace, fields: Sequence[str],
                  overrides: Mapping[str, Mapping] | None = None) -> dict[str, Any]:
    """``{field: value}`` of the options of ``fields`` that were given on the command line (None and unset
    flags are left out), converted by each override's ``convert``; a ValueError from it names the option."""
    values: dict[str, Any] = {}
    for name in fields:
        over = (overrides or {}).get(name, {})
        value = getattr(args, option_dest(name, over), None)
        if value is None or value is False:
            continue
        flag = over.get("flags", ("--" + name.replace("_", "-"),))[0]
        if over.get("negate"):
            value = False
        elif "convert" in over:
            convert: Callable[[Any], Any] = over["convert"]
            try:
                value = convert(value)
            except ValueError as exc:
                message = str(exc)
                raise ValueError(message if flag in message else f"{flag}: {message}") from None
        values[name] = value
    return values


def config_from_args(cls: type, args: argparse.Namespace, fields: Sequence[str],
                     overrides: Mapping[str, Mapping] | None = None, preset: Mapping[str, Any] | None = None,
                     base: Any = None, **extra: Any):
    """The config of the command line: the dataclass defaults (or ``base``), then ``preset``, then the options of
    ``fields`` the user gave, then ``extra`` (values the command computes). The config validates itself."""
    values = {**(preset or {}), **config_values(cls, args, fields, overrides), **extra}
    return dataclasses.replace(base, **values) if base is not None else cls(**values)


def parse_list(text, item: Callable[[str], Any] = str, option: str = "the list", **checks):
    """The one comma-list parser (:func:`nbv.lists.parse_list`; imported on use, so ``--help`` loads nothing)."""
    from nbv.lists import parse_list as parse

    return parse(text, item, option, **checks)


def index_list(text: str | None, option: str, count: int | None = None, what: str | None = None,
               **hints: str) -> tuple[int, ...]:
    """``"0,5"`` -> (0, 5): distinct indices >= 0 (below ``count`` when given); ValueError naming ``option``
    (``hints``: ``empty_hint``, ``range_hint`` of :func:`nbv.lists.parse_list`)."""
    return parse_list(text, int, option, minimum=0, below=count, unique=True, what=what, **hints)


def float_list(text: str, option: str, size: int | None = None) -> tuple[float, ...]:
    """``"1,0,0"`` -> (1.0, 0.0, 0.0): finite numbers (exactly ``size`` of them when given)."""
    return parse_list(text, float, option, size=size, what="number")


# ---- the probe options of simulate, score, sweep, critical, inspect and bench score (nbv.physics.PhysicsConfig) ----
PROBE_FIELDS = ("particle_radius", "steps", "dt", "speed", "viscosity", "directions", "accumulate_every",
                "opacity_threshold")
FRAME_FIELDS = ("up", "scale", "crop")
SOLID_FIELDS = ("fill_cavities",)
RUN_FIELDS = ("empty_reference", "max_memory_gb")


def probe_overrides(default_directions: str = "all five", cameras: bool = False) -> dict[str, dict]:
    """The command line's names and wording for the PhysicsConfig fields whose docstring speaks of the config
    (``cameras``: the command has cameras, so ``--up auto`` is offered)."""
    from fluidsim.directions import DIRECTIONS

    auto = ", or 'auto': the cameras' mean up vector (logged)" if cameras else ""
    return {
        "directions": {"help": f"comma list of probes out of {','.join(DIRECTIONS)}",
                       "default_text": default_directions},
        "up": {"flags": ("--up", "--up-axis"), "metavar": "UP",
               "help": "the scene's up direction, rotated to simulation +y: +x, -x, +y, -y, +z, -z or a vector such "
                       f"as 0,-1,0 (COLMAP captures are often -y){auto}"},
        "scale": {"help": "metres per scene unit, or 'auto': the robust object box's largest extent -> 2 m, the "
                          "paper's domain", "convert": _scale},
        "crop": {"metavar": "BOX", "default_text": "keep all",
                 "help": "keep only the Gaussians inside xmin,ymin,zmin,xmax,ymax,zmax (scene units), or 'auto': "
                         "the robust object box grown by 10 %% per side"},
        "fill_cavities": {"flags": ("--no-fill",), "dest": "no_fill", "negate": True, "default_text": "filled",
                          "help": "keep the solid hollow: do not fill what the Gaussians enclose"},
        "empty_reference": {"flags": ("--no-empty-reference",), "dest": "no_empty_reference", "negate": True,
                            "default_text": "run it", "help": "skip the empty-scene D-bar reference (halves the "
                                                              "run time)"},
    }


def _scale(text: str):
    if str(text).strip().lower() == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"--scale must be 'auto' or a number of metres per scene unit, got {text!r}") from None


def physics_config_class():
    from nbv.physics import QUICK, PhysicsConfig

    return PhysicsConfig, QUICK


def add_frame_arguments(g, cameras: bool = False, scale: bool = True, crop: bool = True) -> None:
    """--up (alias --up-axis), --scale and --crop: the scene -> simulation frame (:mod:`nbv.physics.scene_frame`)."""
    config, _ = physics_config_class()
    names = ("up",) + (("scale",) if scale else ()) + (("crop",) if crop else ())
    add_config_options(g, config, names, probe_overrides(cameras=cameras))


def add_physics_arguments(p: argparse.ArgumentParser, track_distinct: bool = False,
                          empty_reference: bool = True, cameras: bool = False) -> None:
    """The probe options shared by simulate, score, sweep, critical and bench score, generated from
    :class:`nbv.physics.PhysicsConfig` (``empty_reference``: offer --no-empty-reference)."""
    config, quick = physics_config_class()
    over = probe_overrides("-x" if track_distinct else "all five", cameras)
    g = p.add_argument_group("probes")
    g.add_argument("--quick", action="store_true",
                   help=f"quick preset: r = {quick['particle_radius']} m and {quick['steps']} steps per probe (unless "
                        "given explicitly; default: the paper's)")
    add_config_options(g, config, PROBE_FIELDS, over, presets={"--quick": quick})
    add_config_options(g, config, FRAME_FIELDS + SOLID_FIELDS, over)
    g.add_argument("--fill-cavities", action="store_true",
                   help="accepted for old scripts and does nothing: filling is now the default (see --no-fill)")
    add_config_options(g, config, RUN_FIELDS if empty_reference else RUN_FIELDS[1:], over)
    add_runtime_arguments(p)


def add_runtime_arguments(p, threads_help: str = "CPU threads", device_help: str = "compute device") -> None:
    """--device (cpu or cuda; cuda falls back to cpu with a logged warning) and --threads (>= 1)."""
    from .runtime import positive_int

    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help=f"{device_help}; cuda falls back to cpu with a logged warning when unavailable "
                        "(default: cpu)")
    p.add_argument("--threads", type=positive_int, default=None, help=f"{threads_help} (default: all cores)")


def physics_config_from_args(args: argparse.Namespace, track_distinct: bool = False, default_directions=None,
                             cameras=None, preset: Mapping[str, Any] | None = None, **extra):
    """A validated :class:`nbv.physics.PhysicsConfig` from the probe options (``cameras`` for ``--up auto``;
    ``preset``: values under the options', by default :data:`nbv.physics.QUICK` with ``--quick``; ``extra``: fields
    the command sets itself). Options the parser lacks keep the dataclass default."""
    from nbv.physics import parse_directions

    config, quick = physics_config_class()
    values = config_values(config, args, PROBE_FIELDS + FRAME_FIELDS + SOLID_FIELDS + RUN_FIELDS, probe_overrides())
    if "directions" in values:
        values["directions"] = parse_directions(values["directions"])
    elif default_directions:
        values["directions"] = tuple(default_directions)
    if hasattr(args, "up"):
        values["up"] = up_from_args(args, cameras)
    if not hasattr(args, "no_empty_reference"):
        values["empty_reference"] = False  # commands without the option never run the empty scene
    if preset is None:
        preset = quick if getattr(args, "quick", False) else {}
    return config(**{**preset, **values, "track_distinct": track_distinct, **extra})


def up_from_args(args: argparse.Namespace, cameras=None):
    """``args.up`` resolved: an up spec for PhysicsConfig ('auto' -> the cameras' mean up vector, logged)."""
    import logging

    from nbv.physics.scene_frame import describe_auto_up, parse_up

    up = "+y" if args.up is None else args.up
    if str(up).strip().lower() != "auto":
        parse_up(up)  # the error names --up
        return up
    if not cameras:
        raise ValueError("--up auto takes the up direction from cameras, and this command has none; give the up "
                         "direction (--up -y for a y-down COLMAP capture, --up +z for a z-up scene)")
    from recon.frames import up_from_cameras

    vector = up_from_cameras(cameras)
    logging.getLogger("fluidgs").info("%s", describe_auto_up(vector))
    return tuple(float(c) for c in vector)


def add_record_arguments(p: argparse.ArgumentParser) -> None:
    """--record-probe, --record-every, --record-max-gb: keep probes' fluid in RESULT.h5 for `fluidgs view`."""
    g = p.add_argument_group("trajectories (for `fluidgs view`)")
    g.add_argument("--record-probe", default=None, metavar="DIRS",
                   help="record these probes' fluid (positions, D_i, speed) every --record-every steps into RESULT.h5, "
                        "to replay them in `fluidgs view`: a probe (-x) or a comma list (default: none; the file stays "
                        "small)")
    g.add_argument("--record-every", type=int, default=10, metavar="K",
                   help="steps between recorded frames (default: 10); each frame costs 16 bytes per fluid particle")
    g.add_argument("--record-max-gb", type=float, default=2.0,
                   help="refuse, before simulating, a recording larger than this in GiB (default: 2)")


def record_config_from_args(args: argparse.Namespace, config):
    """A :class:`~nbv.physics.trajectory.RecordConfig` from
    --record-probe (None without it), checked against the probes of
    ``config``."""
    if getattr(args, "record_probe", None) is None:
        return None
    from nbv.physics import parse_directions
    from nbv.physics.trajectory import RecordConfig

    try:
        dirs = parse_directions(args.record_probe)
    except ValueError as exc:
        raise ValueError(str(exc).replace("--directions", "--record-probe", 1)) from None
    if not (args.record_max_gb and args.record_max_gb > 0):
        raise ValueError(f"--record-max-gb must be > 0, got {args.record_max_gb}")
    record = RecordConfig(dirs, args.record_every, args.record_max_gb * 2**30)
    record.check_probes(config.directions, config.steps)
    return record


def add_camera_arguments(p: argparse.ArgumentParser) -> None:
    """--cameras, --res, --render-width and --candidates: the candidate views of score and critical."""
    p.add_argument("--cameras", type=Path, required=True,
                   help="Blender/NeRF transforms.json with the candidate cameras, in the Gaussians' frame")
    p.add_argument("--res", type=int, default=None,
                   help="image width in pixels when the cameras file gives no w/h and no images (height from the "
                        "aspect of w/h when known, else square)")
    p.add_argument("--render-width", type=int, default=320,
                   help="render (and weight) at most this width in pixels; the weights pi R^2/(HW) barely change "
                        "with resolution")
    p.add_argument("--candidates", default=None, help="comma list of camera indices to score (default: all)")


# ---- inputs and outputs named on the command line --------------------------------------------------------------
def load_gaussians_checked(path):
    """Load a Gaussian set of any supported format (recon.formats); ValueError naming the file when it is missing,
    a folder or unreadable."""
    from recon.formats import SUPPORTED, load_gaussians

    if not Path(path).exists():  # a folder exists: recon.formats says it is a folder
        raise ValueError(f"Gaussian file {path} does not exist; pass a Gaussian file ({SUPPORTED})")
    return load_gaussians(path).check(str(path))


def check_output_file(path, suffixes: tuple[str, ...]):
    """Fail before any work when ``path`` has the wrong suffix or its folder is not writable."""
    from fluidsim.files import check_writable

    if suffixes and Path(path).suffix.lower() not in suffixes:
        raise ValueError(f"output {path} must end with {' or '.join(suffixes)}")
    return check_writable(path)


# The files of a dataset folder that loading reads (cameras, points, normalisation), at the top, in sparse/ and in
# sparse/0/: no output may overwrite them. Images are left out: no command that reads a dataset writes images.
DATASET_FILES = ("transforms_*.json", "dataset.json", "mesh.ply", "cameras.txt", "cameras.bin", "images.txt",
                 "images.bin", "points3D.txt", "points3D.bin", "points3D.ply")


def dataset_inputs(dataset) -> list[tuple[str, Path]]:
    """("DATASET file", path) for each existing :data:`DATASET_FILES` file of a dataset folder (or the
    transforms_*.json given), for :func:`fluidsim.files.check_not_input`."""
    root = Path(dataset)
    if root.is_file():
        return [("DATASET file", root)]
    return [("DATASET file", f) for folder in (root, root / "sparse", root / "sparse" / "0") if folder.is_dir()
            for pattern in DATASET_FILES for f in sorted(folder.glob(pattern))]


def save_diverged(exc, path: Path | None) -> int:
    """A probe diverged (:class:`nbv.physics.ProbeDiverged`): save the probes completed before it to ``path``
    (RESULT.h5 with status "diverged"; nothing when None), log one line naming the probe and the step; returns 3."""
    import logging

    from nbv.physics import save_result

    log = logging.getLogger("fluidgs")
    if path is None:
        log.error("%s; nothing saved (pass --save-result to keep the completed probes)", exc)
        return 3
    save_result(path, exc.result)
    log.error("%s; the completed probes are saved to %s (status 'diverged'); reduce --dt or --speed", exc, path)
    return 3
