"""The browser viewer (viser): the Gaussians as splats coloured by their own colours or by D_g, the solid, one probe's
fluid replayed over time (opening at mid-run), each probe's reach and the empty-scene reference, the candidate
cameras ranked by S(T), a list of the top views (rank, S(T), coverage and S/A when scores.json has them, a
thumbnail; a click moves the view there), and the leak counts.

Everything is drawn in the simulation frame (metres, Y-up). viser sends a splat's covariance as float16: below
6e-5 m^2 (sigma 8 mm) its values are subnormal, in steps of 6e-8 m^2, which still leaves a Gaussian of sigma 1 mm
within a few per cent of its size (and under a pixel at the usual distances).

:class:`FluidViewer` builds the page from its parts: the Gaussians and the probe table here, the solid, the leaks and
the fluid replay in :mod:`viz.fluid_panel`, the cameras and the list of the top views in :mod:`viz.camera_panel`;
:mod:`viz.serving` holds the options, the address check and the serve loop.

Example:
    >>> viewer = open_viewer("out/demo/result.h5", scores="out/demo/scores.json")  # doctest: +SKIP
    >>> print(viewer.url)  # doctest: +SKIP
    http://127.0.0.1:8080
    >>> viewer.wait()  # until Ctrl-C  # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import io
import logging
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np

from fluidsim.files import check_input_file

from .camera_panel import CameraPanel
from .cameras import CandidateView, cameras_path_of, candidate_views, read_scores, view_png
from .colors import color_scale, colorbar_image, turbo
from .data import Trajectory, ViewData, load_view_data
from .fluid_panel import FluidPanel
from .serving import ViewerOptions, check_address, import_viser, is_loopback
from .splats import SplatLooks, splat_looks

log = logging.getLogger(__name__)

OWN_COLORS = "own colours"
# the direction each probe's fluid flows (fluidsim.probes.flow_vector, restated: fluidsim loads Taichi)
PROBE_FLOWS = {
    "-x": (-1.0, 0.0, 0.0),
    "+x": (1.0, 0.0, 0.0),
    "-z": (0.0, 0.0, -1.0),
    "+z": (0.0, 0.0, 1.0),
    "-y": (0.0, -1.0, 0.0),
}
BACKGROUND = "white"


class FluidViewer(FluidPanel, CameraPanel):
    """A running viser server showing one RESULT.h5 (see the module docstring).

    Args:
        data: RESULT.h5's arrays (:func:`viz.data.load_view_data`).
        looks: the Gaussians' colours and opacities (:func:`viz.splats.splat_looks`).
        views: the candidate cameras, simulation frame (:func:`viz.cameras.candidate_views`), maybe empty.
        options: host, port, first probe.
    """

    def __init__(
        self, data: ViewData, looks: SplatLooks, views: list[CandidateView], options: ViewerOptions | None = None
    ):
        viser = import_viser()
        self.data, self.looks, self.views = data, looks, views
        self.options = options or ViewerOptions()
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._trajectory: Trajectory | None = None
        self._frame = 0
        self._playing = False
        self._uncertainty = None  # the GUI image of a view's composited D_g (scores.json with uncertainty images)
        self._fluid_vmax = {"divergence": 1.0, "speed": 1.0}
        self._fluid_bar_of: tuple[str, str] | None = None
        self._shown_probe: str | None = None
        self._frustums: list = []
        with contextlib.redirect_stdout(io.StringIO()):  # viser prints a banner; `fluidgs view` prints one line
            self.server = viser.ViserServer(
                host=self.options.host, port=self.options.port, label="FluidGaussian", verbose=False
            )
        self.port = int(self.server.get_port())
        if self.options.port and self.port != self.options.port:  # taken between check_address and now
            log.warning("port %d is in use; serving on port %d instead", self.options.port, self.port)
        self.server.gui.configure_theme(show_share_button=False, control_width="medium")
        self.server.scene.set_up_direction("+y")
        self._centre, self._extent = self._object_box()
        self._add_splats()
        self._add_probes()
        self._add_solid()
        self._add_fluid()
        self._add_cameras()
        self._add_view_list()
        self._set_initial_camera()
        self._player = threading.Thread(target=self._play_loop, name="fluidgs-view-player", daemon=True)
        self._player.start()

    # ---- what it serves --------------------------------------------------------------------------
    @property
    def url(self) -> str:
        host = self.options.host
        shown = {"0.0.0.0": "127.0.0.1", "::": "[::1]"}.get(host, f"[{host}]" if ":" in host else host)
        return f"http://{shown}:{self.port}"

    def _object_box(self) -> tuple[np.ndarray, float]:
        """(centre [3], largest extent) of the solid the probes saw, m (without a solid: the robust box, 0.5-99.5 %
        quantiles, of the simulated Gaussians' centres)."""
        d = self.data
        if len(d.solid):
            lo, hi = d.solid.min(axis=0), d.solid.max(axis=0)
        else:
            means = d.means if d.kept is None else d.means[d.kept]
            means = means if len(means) else np.zeros((1, 3))
            lo, hi = np.quantile(means, 0.005, axis=0), np.quantile(means, 0.995, axis=0)
        return (lo + hi) / 2.0, max(float((hi - lo).max()), 4.0 * d.particle_radius)

    # ---- Gaussians -------------------------------------------------------------------------------
    def _splat_subset(self) -> np.ndarray:
        """[G] bool, the Gaussians drawn (all, or the simulated ones when the crop is hidden)."""
        show_all = self.data.kept is None or self._show_cropped.value
        return np.ones(self.data.num_gaussians, bool) if show_all else self.data.kept

    def _color_modes(self) -> list[str]:
        modes = ["D_g max", "D_g mean", *(f"D_g {d}" for d in self.data.directions)]
        return modes + [OWN_COLORS] if self.looks.rgb is not None else modes

    def _add_splats(self) -> None:
        gui = self.server.gui
        d = self.data
        empty = "not run" if not np.isfinite(d.dbar_empty) else f"{d.dbar_empty:.4g} m^4/s"
        gui.add_markdown(
            f"**{d.path.name}**: {d.num_gaussians:,} Gaussians, probes {', '.join(d.directions)}; "
            f"D-bar {d.dbar:.4g} m^4/s (empty scene: {empty})"
        )
        with gui.add_folder("Gaussians"):
            self._color_mode = gui.add_dropdown(
                "colour",
                self._color_modes(),
                initial_value="D_g max",
                hint="their own colours (SH DC) or D_g, max or mean over the probes or one probe's, on the TURBO map; "
                "grey: no probe's fluid reached the Gaussian (its D_g = 0 is unmeasured, not calm)",
            )
            self._colorbar = gui.add_image(colorbar_image(1.0, "D_g (max), 1/s"), format="png")
            self._show_splats = gui.add_checkbox("show Gaussians", True)
            self._show_cropped = gui.add_checkbox(
                "show Gaussians outside the crop",
                False,
                visible=d.kept is not None,
                hint="they were not simulated: their D_g is 0",
            )
        keep, (rgb, _) = self._splat_subset(), self.splat_colors("D_g max")  # set_color_mode then sends nothing new
        self._splats = self.server.scene.add_gaussian_splats(
            "/gaussians",
            centers=d.means[keep],
            covariances=d.covariances[keep],
            rgbs=rgb[keep],
            opacities=self.looks.opacity[keep].reshape(-1, 1),
        )
        self._color_mode.on_update(lambda _: self.set_color_mode(self._color_mode.value))
        self._show_cropped.on_update(lambda _: self.set_color_mode(self._color_mode.value))
        self._show_splats.on_update(lambda _: setattr(self._splats, "visible", self._show_splats.value))
        self.set_color_mode("D_g max")

    def splat_colors(self, mode: str) -> tuple[np.ndarray, float | None]:
        """([G, 3] float32 RGB, the D_g at the top of the scale or None) of a colour mode of the dropdown."""
        if mode == OWN_COLORS:
            if self.looks.rgb is None:
                raise ValueError("no own colours without --gaussians")
            return self.looks.rgb, None
        if not mode.startswith("D_g "):
            raise ValueError(f"unknown colour mode {mode!r}; one of {self._color_modes()}")
        values = self.data.metric(mode[4:])
        counted = np.ones(len(values), bool) if self.data.kept is None else self.data.kept.copy()
        if self.data.reached_gaussians is not None:
            counted &= self.data.reached_gaussians
        vmax = color_scale(values[counted])
        return turbo(values, vmax, self.data.reached_gaussians), vmax

    def set_color_mode(self, mode: str) -> None:
        """Colour the splats by ``mode`` (an entry of the dropdown) and redraw the colour bar."""
        rgb, vmax = self.splat_colors(mode)
        keep = self._splat_subset()
        d = self.data
        with self._lock, self.server.atomic():
            self._splats.set_gaussians(
                centers=d.means[keep],
                covariances=d.covariances[keep],
                rgbs=rgb[keep],
                opacities=self.looks.opacity[keep].reshape(-1, 1),
            )
            if vmax is not None:
                grey = "" if d.reached_gaussians is None or d.reached_gaussians.all() else " (grey: not reached)"
                self._colorbar.image = colorbar_image(vmax, f"{mode}, 1/s{grey}")
            self._colorbar.visible = vmax is not None
            if self._color_mode.value != mode:
                self._color_mode.value = mode

    # ---- probes: reach and the empty-scene reference ----------------------------------------------
    def probe_markdown(self) -> str:
        """Per probe: the Gaussians its fluid reached, the mean D_g, and the empty scene's mean D_g (the reference:
        what the same probe reads with no solid)."""
        d = self.data
        rows = []
        for p in d.directions:
            reached = d.reached.get(p)
            share = "n/a" if reached is None else f"{reached:,} ({100.0 * reached / max(d.num_gaussians, 1):.0f} %)"
            empty = d.empty_per_probe.get(p)
            rows.append(
                f"| {p} | {share} | {float(np.mean(d.per_probe[p])):.3g} | "
                f"{'n/a' if empty is None else f'{float(np.mean(empty)):.3g}'} |"
            )
        ratio = f" (x{d.dbar / d.dbar_empty:.3g})" if np.isfinite(d.dbar_empty) and d.dbar_empty > 0 else ""
        empty = (
            "the empty scene was not run (re-run simulate without --no-empty-reference)"
            if not np.isfinite(d.dbar_empty)
            else f"empty scene D-bar {d.dbar_empty:.4g} m^4/s{ratio}"
        )
        return "\n".join(
            [
                f"D-bar {d.dbar:.4g} m^4/s; {empty}",
                "",
                "| probe | Gaussians reached | mean D_g, 1/s | empty scene, 1/s |",
                "|---|---|---|---|",
                *rows,
            ]
        )

    def _add_probes(self) -> None:
        with self.server.gui.add_folder("Probes: reach and the empty scene", expand_by_default=False):
            self._probe_table = self.server.gui.add_markdown(self.probe_markdown())

    # ---- the first view --------------------------------------------------------------------------
    def _set_initial_camera(self) -> None:
        """A view from a little above, downstream of the replayed probe and to its side (the fluid comes towards the
        object from behind it), outside the candidate cameras (at most 5 object sizes away)."""
        cam = self.server.initial_camera
        flow = np.asarray(PROBE_FLOWS.get(self._probe.value, (0.0, -1.0, 0.0)))
        side = np.array([flow[2], 0.0, -flow[0]])  # the flow turned 90 degrees about +y
        direction = 0.7 * flow + side + np.array([0.0, 0.5, 0.0]) if flow[1] == 0 else np.array([0.35, 0.5, 1.0])
        reach = max((float(np.linalg.norm(v.position - self._centre)) for v in self.views), default=0.0)
        distance = min(max(1.4 * self._extent, 1.3 * reach), 5.0 * self._extent)
        cam.position = tuple(self._centre + distance * direction / np.linalg.norm(direction))
        cam.look_at = tuple(self._centre)
        cam.up = (0.0, 1.0, 0.0)

    # ---- life ------------------------------------------------------------------------------------
    def wait(self) -> None:
        """Serve until :meth:`close` (from another thread) or Ctrl-C (KeyboardInterrupt, raised to the caller)."""
        while not self._stop.wait(0.5):
            pass

    def close(self) -> None:
        """Stop the replay and the server (quietly: viser's own 'Server stopped' line is swallowed)."""
        self._stop.set()
        if self._player.is_alive() and threading.current_thread() is not self._player:
            self._player.join(timeout=2.0)
        with contextlib.redirect_stdout(io.StringIO()):
            self.server.stop()


def open_viewer(
    result: str | Path,
    gaussians: str | Path | None = None,
    scores: str | Path | None = None,
    cameras: str | Path | None = None,
    options: ViewerOptions | None = None,
) -> FluidViewer:
    """Read everything, check that it belongs together, and start the server.

    Args:
        result: RESULT.h5 of `fluidgs simulate` (or `score --save-result`).
        gaussians: the Gaussian file it was computed from (None: RESULT.h5's source when it exists).
        scores: scores.json of `fluidgs score` (ranks and S(T) of the candidate cameras), or None.
        cameras: the candidates' transforms.json (None: the one scores.json names, when it exists).
        options: host, port, first probe.
    Raises:
        ValueError: bad or mismatched inputs (the message names the file and the fix); viser not installed.
    """
    options = options or ViewerOptions()
    import_viser()
    options = replace(options, port=check_address(options.host, options.port))  # before reading anything
    data = load_view_data(result)
    bad = int(np.count_nonzero(~np.isfinite(data.divergence)))
    if bad:
        log.warning(
            "%s: %d of %d Gaussians have a non-finite D_g (NaN or infinite: a diverged or corrupted "
            "result); they are drawn as D_g = 0 (dark blue). Re-run `fluidgs simulate` for a sound result",
            data.path,
            bad,
            len(data.divergence),
        )
    if options.probe is not None and options.probe not in data.directions:
        raise ValueError(f"--probe {options.probe}: {data.path} has the probes {', '.join(data.directions)}")
    looks = splat_looks(gaussians, data)
    score_data = read_scores(scores) if scores is not None else None
    if cameras is None and score_data is not None:
        cameras = cameras_path_of(score_data, Path(scores))
        if cameras is None:
            raise ValueError(
                f"--scores {scores} names the cameras {score_data.get('cameras')!r}, which are not "
                "there; pass --cameras transforms.json"
            )
    if cameras is not None:
        check_input_file(cameras, "--cameras", "pass the transforms.json of the candidate cameras")
    views = candidate_views(cameras, data.scene_to_sim, score_data, str(data.path)) if cameras is not None else []
    if scores is not None:
        views = [replace(v, png=view_png(scores, v)) for v in views]
    if not is_loopback(options.host):
        log.warning(
            "serving on %s: anyone who can reach this machine on port %d can open the viewer",
            options.host,
            options.port,
        )
    return FluidViewer(data, looks, views, options)
