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

from .attributes import field_docs, help_and_default
from .cameras import (
    CAMERAS_HELP,
    add_camera_arguments,
    add_orbit_arguments,
    add_visibility_arguments,
    camera_file_from_args,
    check_visibility_arguments,
    orbit_cameras_logged,
    orbit_from_args,
)
from .fields import (
    add_config_options,
    config_from_args,
    config_values,
    float_list,
    index_list,
    option_dest,
    option_names,
    options_named,
    parse_list,
)
from .files import (
    add_gaussian_file_arguments,
    add_gaussians_input,
    check_output_file,
    check_output_folder,
    check_outside_dataset,
    dataset_inputs,
    gaussian_file_inputs,
    load_gaussians_checked,
)
from .frame import check_up_against_cameras, frame_hint, up_from_args, warn_frame
from .groups import (
    add_frame_arguments,
    add_physics_arguments,
    add_runtime_arguments,
    physics_config_class,
    physics_config_from_args,
    probe_overrides,
)
from .results import add_record_arguments, record_config_from_args, result_overridden_options, save_diverged

__all__ = [
    "CAMERAS_HELP",
    "add_orbit_arguments",
    "camera_file_from_args",
    "check_up_against_cameras",
    "frame_hint",
    "orbit_cameras_logged",
    "orbit_from_args",
    "result_overridden_options",
    "warn_frame",
    "physics_config_class",
    "add_camera_arguments",
    "add_config_options",
    "add_frame_arguments",
    "add_physics_arguments",
    "add_record_arguments",
    "add_runtime_arguments",
    "add_visibility_arguments",
    "check_output_file",
    "check_output_folder",
    "check_visibility_arguments",
    "config_from_args",
    "config_values",
    "check_outside_dataset",
    "dataset_inputs",
    "gaussian_file_inputs",
    "field_docs",
    "float_list",
    "help_and_default",
    "index_list",
    "load_gaussians_checked",
    "add_gaussian_file_arguments",
    "add_gaussians_input",
    "option_dest",
    "option_names",
    "options_named",
    "parse_list",
    "physics_config_from_args",
    "probe_overrides",
    "record_config_from_args",
    "save_diverged",
    "up_from_args",
]
