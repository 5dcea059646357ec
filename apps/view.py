"""`fluidgs view RESULT.h5`: the fluid against your splat in a browser (viser; :mod:`viz`).

Serves, on 127.0.0.1 unless ``--host`` says otherwise, a page that shows the Gaussians coloured by their own
colours or by D_g with a colour bar (1/s), the solid particles, one probe's fluid replayed over time (when
RESULT.h5 holds its trajectory: ``fluidgs simulate ... --record-probe -x``), the candidate cameras of
``--scores`` coloured by S(T) with their rank (a click moves the view to one), and the leak counts. Ctrl-C stops it.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger("fluidgs")


FIELDS = ("probe", "port", "host")
OVERRIDES = {
    "probe": {
        "metavar": "DIR",
        "default_text": "the first recorded",
        "help": "the probe whose fluid is replayed: -x, +x, -z, +z or -y",
    },
    "port": {"help": "port; a port in use moves to the next free one, logged; 0: any free port"},
    "host": {
        "help": "address to bind (127.0.0.1: this machine only; 0.0.0.0 serves every interface, to "
        "anyone who can reach it)"
    },
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("result", type=Path, help="RESULT.h5 of `fluidgs simulate` (or `fluidgs score --save-result`)")
    p.add_argument(
        "--gaussians",
        type=Path,
        default=None,
        help="the Gaussian file RESULT.h5 was computed from, for their own colours and opacities "
        "(default: the source recorded in RESULT.h5, when it exists)",
    )
    p.add_argument(
        "--scores",
        type=Path,
        default=None,
        help="scores.json of `fluidgs score`: the candidate cameras coloured by S(T), with their rank "
        "(default: none; then --cameras alone draws them uncoloured)",
    )
    p.add_argument(
        "--cameras",
        type=Path,
        default=None,
        help="the candidates' cameras file (transforms.json, COLMAP model, graphdeco cameras.json), "
        "scene units (default: the file --scores names)",
    )
    p.add_argument(
        "--screenshot",
        type=Path,
        default=None,
        metavar="PNG",
        help="write a PNG of the page as headless Chromium draws it, then exit instead of serving (needs chromium on "
        "PATH; default: serve until Ctrl-C)",
    )
    from viz.serving import ViewerOptions

    from .options import add_config_options

    add_config_options(p, ViewerOptions, FIELDS, OVERRIDES)


def run_command(args: argparse.Namespace) -> int:
    from viz.serving import ViewerOptions, serve
    from viz.viewer import open_viewer

    from .options import config_from_args

    logging.getLogger("websockets").setLevel(logging.WARNING)  # one line per connection otherwise
    options = config_from_args(ViewerOptions, args, FIELDS, OVERRIDES)
    if args.screenshot is not None:
        from viz.screenshot import ScreenshotUnavailable, find_browser

        from .options import check_output_file

        check_output_file(args.screenshot, (".png",))
        if find_browser() is None:  # before the viewer loads anything
            raise ScreenshotUnavailable(
                "--screenshot needs Chromium (chromium, chromium-browser or google-chrome on PATH), and none is "
                "installed; install it (Debian/Ubuntu: apt-get install chromium), or run `fluidgs view` without "
                "--screenshot, open its address in a browser and save the picture from there"
            )
    viewer = open_viewer(
        args.result, gaussians=args.gaussians, scores=args.scores, cameras=args.cameras, options=options
    )
    if args.screenshot is not None:
        from viz.screenshot import screenshot

        try:
            print(f"screenshot: {screenshot(viewer.url, args.screenshot)}")
        finally:
            viewer.close()
        return 0
    return serve(viewer, announce=lambda line: print(line, flush=True))
