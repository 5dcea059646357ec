"""The options around RESULT.h5: the recorded probes (--record-probe), the options a --result fixes, and the
save of a diverged run's completed probes."""

from __future__ import annotations

import argparse
from pathlib import Path

from .groups import FRAME_FIELDS, PROBE_FIELDS, REPLICA_FIELDS, RUN_FIELDS, SOLID_FIELDS, probe_overrides


def add_record_arguments(p: argparse.ArgumentParser) -> None:
    """--record-probe, --record-every, --record-max-gb: keep probes' fluid in RESULT.h5 for `fluidgs view`."""
    g = p.add_argument_group("trajectories (for `fluidgs view`)")
    g.add_argument(
        "--record-probe",
        default=None,
        metavar="DIRS",
        help="record these probes' fluid (positions, D_i, speed) every --record-every steps into RESULT.h5, "
        "to replay them in `fluidgs view`: a probe (-x) or a comma list (default: none; the file stays "
        "small)",
    )
    g.add_argument(
        "--record-every",
        type=int,
        default=10,
        metavar="K",
        help="steps between recorded frames (default: 10); each frame costs 24 bytes per fluid particle",
    )
    g.add_argument(
        "--record-max-gb",
        type=float,
        default=2.0,
        help="refuse, before simulating, a recording larger than this in GiB (default: 2)",
    )


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


# ---- --result: the options it fixes -----------------------------------------------------------------------------
def result_overridden_options(args: argparse.Namespace) -> list[str]:
    """The probe, frame and solid options given on the command line (``"--up -y"``, ``"--quick"``): a RESULT.h5
    fixes all of them, so with ``--result`` they are ignored."""
    over = probe_overrides()
    given = ["--quick"] if getattr(args, "quick", False) else []
    for name in PROBE_FIELDS + FRAME_FIELDS + SOLID_FIELDS + RUN_FIELDS + REPLICA_FIELDS:
        o = over.get(name, {})
        dest = o.get("dest", name)
        value = getattr(args, dest, None)
        if value is None or value is False:
            continue
        flag = o.get("flags", ("--" + name.replace("_", "-"),))[0]
        given.append(flag if value is True else f"{flag} {value}")
    if getattr(args, "fill_cavities", False):
        given.append("--fill-cavities")
    return given


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
