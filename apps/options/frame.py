"""The scene -> simulation frame on the command line: --scale's value, --up resolved (``auto``: the cameras' mean
up), and the hints logged when the up direction was not given or disagrees with the cameras."""

from __future__ import annotations

import argparse


def scale_value(text: str):
    """--scale: 'auto' or a number of metres per scene unit (ValueError naming the option)."""
    if str(text).strip().lower() == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"--scale must be 'auto' or a number of metres per scene unit, got {text!r}") from None


def up_from_args(args: argparse.Namespace, cameras=None):
    """``args.up`` resolved: an up spec for PhysicsConfig ('auto' -> the cameras' mean up vector, logged)."""
    import logging

    from nbv.orbit import orbit_count
    from nbv.physics.scene_frame import describe_auto_up, parse_up

    up = "+y" if args.up is None else args.up
    if str(up).strip().lower() != "auto":
        parse_up(up)  # the error names --up
        return up
    if orbit_count(getattr(args, "cameras", None) or "") is not None:
        raise ValueError(
            "--up auto takes the up direction from a camera file, and --cameras orbit:N builds its "
            "cameras around --up; give the up direction (--up -y for a y-down COLMAP capture, --up +z "
            "for a z-up scene)"
        )
    if not cameras:
        raise ValueError(
            "--up auto takes the up direction from cameras, and this command has none; give the up "
            "direction (--up -y for a y-down COLMAP capture, --up +z for a z-up scene)"
        )
    from recon.frames import up_from_cameras

    vector = up_from_cameras(cameras)
    logging.getLogger("fluidgs").info("%s", describe_auto_up(vector))
    return tuple(float(c) for c in vector)


# ---- frame hints ---------------------------------------------------------------------------------------------
UP_DISAGREES_DEG = 60.0  # warn when --up is further than this from the cameras' mean up


def frame_hint() -> str:
    """The one line said when --up is not given: the up assumed, and the usual fix for COLMAP captures."""
    return (
        "frame: no --up given, so the file's +y axis is taken as up (the top probe falls along -y); COLMAP "
        "captures are usually y-down: pass --up -y for them (`fluidgs inspect --png` shows which way is up)"
    )


def check_up_against_cameras(up, cameras, what: str = "the cameras") -> str | None:
    """A warning when the up direction ``up`` (anything :func:`nbv.physics.scene_frame.parse_up` takes) is more
    than :data:`UP_DISAGREES_DEG` from ``cameras``' mean up vector; None when they agree (or the cameras have no
    consistent up)."""
    from nbv.orbit import angle_to_camera_up
    from nbv.physics.scene_frame import nearest_axis, parse_up, up_label

    u = parse_up(up)
    found = angle_to_camera_up(u, cameras)
    if found is None or found[0] <= UP_DISAGREES_DEG:
        return None
    angle, mean = found
    axis, off = nearest_axis(mean)
    return (
        f"the up direction {up_label(u)} is {angle:.0f} deg from {what}' mean up ({up_label(mean)}, {off:.0f} deg "
        f"from {axis}): the capture would be simulated {'upside down' if angle > 120 else 'on its side'}; pass "
        f"--up {axis} (or --up auto to take the cameras' mean up)"
    )


def warn_frame(config, cameras=None, up_given: bool = True, what: str = "the cameras") -> None:
    """Log the frame hint when the up direction was not given (``up_given`` False), and the camera-up warning when
    ``cameras`` disagree with ``config.up``."""
    import logging

    log = logging.getLogger("fluidgs")
    if not up_given:
        log.info("%s", frame_hint())
    if cameras:
        warning = check_up_against_cameras(config.up, cameras, what)
        if warning:
            log.warning("%s", warning)
