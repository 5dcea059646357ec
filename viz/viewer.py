"""The browser viewer (viser): the Gaussians as splats coloured by their own colours or by D_g, the solid, one probe's
fluid replayed over time (opening at mid-run), each probe's reach and the empty-scene reference, the candidate
cameras ranked by S(T), a list of the top views (rank, S(T), coverage and S/A when scores.json has them, a
thumbnail; a click moves the view there), and the leak counts.

Everything is drawn in the simulation frame (metres, Y-up). viser sends a splat's covariance as float16: below
6e-5 m^2 (sigma 8 mm) its values are subnormal, in steps of 6e-8 m^2, which still leaves a Gaussian of sigma 1 mm
within a few per cent of its size (and under a pixel at the usual distances).

Example:
    >>> viewer = open_viewer("out/demo/result.h5", scores="out/demo/scores.json")  # doctest: +SKIP
    >>> print(viewer.url)  # doctest: +SKIP
    http://127.0.0.1:8080
    >>> viewer.wait()  # until Ctrl-C  # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import errno
import io
import ipaddress
import logging
import signal
import socket
import threading
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from fluidsim.files import check_input_file

from .cameras import CandidateView, cameras_path_of, candidate_views, read_scores, view_png
from .colors import color_scale, colorbar_image, score_colors, turbo
from .data import Trajectory, ViewData, load_trajectory, load_view_data, no_trajectory_message
from .splats import SplatLooks, splat_looks
from .thumbnails import view_thumbnail

log = logging.getLogger(__name__)

OWN_COLORS = "own colours"
FLUID_VALUES = {"D_i, 1/s": "divergence", "speed, m/s": "speed"}
SOLID_RGB = (150, 150, 150)
# the direction each probe's fluid flows (fluidsim.probes.flow_vector, restated: fluidsim loads Taichi)
PROBE_FLOWS = {
    "-x": (-1.0, 0.0, 0.0),
    "+x": (1.0, 0.0, 0.0),
    "-z": (0.0, 0.0, -1.0),
    "+z": (0.0, 0.0, 1.0),
    "-y": (0.0, -1.0, 0.0),
}
LEAK_RGB = (255, 0, 255)
BACKGROUND = "white"
# values sampled to pick a trajectory's colour scale (the 99th percentile over all its frames)
SCALE_SAMPLES = 2_000_000
TOP_VIEWS = 10  # views in the list of the side panel
INSTALL_HINT = "`fluidgs view` needs viser: pip install -e .[view] (or pip install 'viser>=1.0')"


def _two_digits(value: float) -> str:
    """``value`` rounded to two significant digits, as ``fluidgs score`` prints it (360, 4.9)."""
    return f"{float(f'{value:.2g}'):g}"


@dataclass(frozen=True)
class ViewerOptions:
    """Where to serve and what to show first.

    Attributes:
        host: the address to bind (127.0.0.1: this machine only; 0.0.0.0: every interface).
        port: the port (0: any free one); a port in use moves to the next free one, logged.
        probe: the probe whose fluid is replayed (None: the first recorded one, else the first probe).
        fps: replay frames per second.
    """

    host: str = "127.0.0.1"
    port: int = 8080
    probe: str | None = None
    fps: float = 10.0

    def __post_init__(self) -> None:
        if isinstance(self.port, bool) or not isinstance(self.port, int) or not 0 <= self.port <= 65535:
            raise ValueError(f"--port must be an integer in 0..65535 (0: any free port), got {self.port!r}")
        if not isinstance(self.host, str) or not self.host.strip():
            raise ValueError(f"--host must be an address such as 127.0.0.1, got {self.host!r}")
        if not self.fps > 0:
            raise ValueError(f"--fps must be > 0 frames per second, got {self.fps}")


def import_viser():
    """viser, or a ValueError saying how to install it."""
    try:
        import viser  # noqa: PLC0415 - the optional 'view' extra
    except ImportError as exc:
        raise ValueError(f"{INSTALL_HINT} ({exc})") from None
    return viser


PORT_TRIES = 64  # a port in use moves up to this many ports on


def check_address(host: str, port: int) -> int:
    """The port to serve on: ``port`` when it is free on ``host``, else the next free one of :data:`PORT_TRIES`
    (logged), or 0 for 0 (any free port). Tried with a plain socket before the server starts, so that a bad address
    or a full range is a clear error at once (viser would wait forever or print a traceback).

    Raises:
        ValueError: ``host`` does not resolve or is not an address of this machine; no port is free; a port below
            1024 needs privileges.
    """
    try:
        infos = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise ValueError(
            f"--host {host}: not a name or address this machine can resolve ({exc}); use 127.0.0.1, "
            "0.0.0.0 or an address of this machine"
        ) from None
    family, _, _, _, addr = infos[0]
    last = 65535 if port == 0 else min(port + PORT_TRIES - 1, 65535)
    for candidate in range(port, last + 1):
        with socket.socket(family, socket.SOCK_STREAM) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as a server binds
            try:
                sock.bind((addr[0], candidate, *addr[2:]))
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE:
                    continue
                if exc.errno == errno.EADDRNOTAVAIL:
                    raise ValueError(
                        f"--host {host} is not an address of this machine; use 127.0.0.1 (this machine "
                        "only), 0.0.0.0 (every interface) or one of its own addresses"
                    ) from None
                if exc.errno == errno.EACCES:
                    raise ValueError(
                        f"--port {candidate} needs administrator privileges (ports below 1024); choose "
                        "a port from 1024 up, or 0 for any free port"
                    ) from None
                raise ValueError(
                    f"--host {host} --port {candidate}: cannot serve there ({exc.strerror}); choose "
                    "another --host or --port"
                ) from None
        if candidate != port and port != 0:
            log.warning("port %d is in use; serving on port %d instead", port, candidate)
        return 0 if port == 0 else candidate
    raise ValueError(
        f"--port {port} is in use, and so is every port up to {last}; choose another --port (0: any free port)"
    )


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class FluidViewer:
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
                hint="their own colours (SH DC) or D_g, max or mean over the probes or one probe's, on the TURBO map",
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
        shown = values if self.data.kept is None else values[self.data.kept]
        vmax = color_scale(shown)
        return turbo(values, vmax), vmax

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
                self._colorbar.image = colorbar_image(vmax, f"{mode}, 1/s")
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

    # ---- solid and leaks -------------------------------------------------------------------------
    def _add_solid(self) -> None:
        gui, d = self.server.gui, self.data
        r = d.particle_radius
        with gui.add_folder("Solid"):
            show = gui.add_checkbox(
                f"solid particles ({len(d.solid):,})",
                False,
                hint="the boundary particles the probes flowed against (sim metres)",
            )
        self._solid = self.server.scene.add_point_cloud(
            "/solid",
            points=d.solid.astype(np.float32),
            colors=SOLID_RGB,
            point_size=r,
            point_shape="circle",
            visible=False,
        )
        show.on_update(lambda _: setattr(self._solid, "visible", show.value))

    def _leak_markdown(self) -> str:
        if not self.data.leaks:
            return "leaks: not recorded in this file (re-run `fluidgs simulate` to count them)"
        rows = [
            f"| {d} | {lk.final:,} | {lk.max:,}" + (f" (step {lk.max_step + 1})" if lk.max else "") + " |"
            for d, lk in self.data.leaks.items()
        ]
        return "\n".join(["fluid inside the filled solid", "", "| probe | at the end | most |", "|---|---|---|", *rows])

    # ---- fluid -----------------------------------------------------------------------------------
    def _first_probe(self) -> str:
        d = self.data
        probe = self.options.probe or (d.recorded[0] if d.recorded else d.directions[0])
        if probe not in d.directions:
            raise ValueError(f"--probe {probe}: {d.path} has the probes {', '.join(d.directions)}")
        return probe

    def _add_fluid(self) -> None:
        gui, d = self.server.gui, self.data
        probe = self._first_probe()
        with gui.add_folder("Fluid"):
            self._probe = gui.add_dropdown("probe", list(d.directions), initial_value=probe)
            self._fluid_note = gui.add_markdown("")
            self._fluid_by = gui.add_dropdown("colour by", list(FLUID_VALUES), initial_value="D_i, 1/s")
            self._play = gui.add_button("Play", hint="play / pause the replay")
            self._slider = gui.add_slider("frame", 0, 1, 1, 0)
            self._fluid_bar = gui.add_image(colorbar_image(1.0, "D_i, 1/s"), format="png")
            self._show_leaks = gui.add_checkbox(
                "leaked particles (end)", True, hint="fluid particles inside the filled solid at the probe's end"
            )
            gui.add_markdown(self._leak_markdown())
        self._fluid = self.server.scene.add_point_cloud(
            "/fluid",
            points=np.zeros((1, 3), np.float32),
            colors=(0, 0, 255),
            point_size=0.8 * d.particle_radius,
            point_shape="circle",
            visible=False,
        )
        self._leaked = self.server.scene.add_point_cloud(
            "/leaked",
            points=np.zeros((1, 3), np.float32),
            colors=LEAK_RGB,
            point_size=1.5 * d.particle_radius,
            point_shape="circle",
            visible=False,
        )
        self._probe.on_update(lambda _: self.set_probe(self._probe.value))
        self._fluid_by.on_update(lambda _: self.show_frame(self._frame))
        self._slider.on_update(lambda _: self.show_frame(int(self._slider.value)))
        self._play.on_click(lambda _: self.set_playing(not self._playing))
        self._show_leaks.on_update(lambda _: self._update_leaks())
        self.set_probe(probe)

    def set_probe(self, probe: str) -> None:
        """Replay ``probe``'s fluid (or say how to record it when it has no trajectory)."""
        d = self.data
        with self._lock:
            if probe == self._shown_probe:  # the dropdown's own update, when set from here
                return
            self._shown_probe = probe
            self.set_playing(False)
            if probe in d.recorded:
                self._trajectory = load_trajectory(d, probe)
                t = self._trajectory
                for key in FLUID_VALUES.values():
                    values = getattr(t, key).reshape(-1)
                    stride = max(1, values.size // SCALE_SAMPLES)
                    self._fluid_vmax[key] = color_scale(values[::stride].astype(np.float32))
                self._slider.max = max(t.num_frames - 1, 1)
                self._slider.disabled = self._play.disabled = self._fluid_by.disabled = False
            else:
                self._trajectory = None
                message = no_trajectory_message(d, probe)
                log.warning("%s", message)
                self._fluid_note.content = message.replace("re-run `", "re-run\n\n`", 1)
                self._slider.disabled = self._play.disabled = self._fluid_by.disabled = True
            self._fluid_bar.visible = self._trajectory is not None
            self._fluid.visible = self._trajectory is not None
            if self._probe.value != probe:
                self._probe.value = probe
            self._update_leaks()
            self._frame, self._fluid_bar_of = -1, None
            # mid-run: the fluid around the object (the last frame shows it pooled on the floor)
            self.show_frame(0 if self._trajectory is None else self._trajectory.num_frames // 2)

    def _update_leaks(self) -> None:
        lk = self.data.leaks.get(self._probe.value)
        has = lk is not None and len(lk.x_leaked) > 0
        with self.server.atomic():
            if has:
                self._leaked.points = lk.x_leaked.astype(np.float32)
                self._leaked.colors = np.tile(np.asarray(LEAK_RGB, np.uint8), (len(lk.x_leaked), 1))
            self._leaked.visible = has and self._show_leaks.value

    def fluid_colors(self, values: np.ndarray, key: str) -> np.ndarray:
        """[K, 3] uint8 colours of D_i or speed values on the trajectory's fixed scale."""
        return np.round(turbo(values, self._fluid_vmax[key]) * 255).astype(np.uint8)

    def show_frame(self, index: int) -> None:
        """Draw frame ``index`` of the replayed probe (no-op without a trajectory)."""
        t = self._trajectory
        if t is None:
            return
        index = int(np.clip(index, 0, t.num_frames - 1))
        key = FLUID_VALUES[self._fluid_by.value]
        with self._lock:
            x, values = t.frame(index, key)
            self._frame = index
            with self.server.atomic():
                if len(x):
                    self._fluid.points = x
                    self._fluid.colors = self.fluid_colors(values, key)
                self._fluid.visible = len(x) > 0  # hidden when every particle has left the domain
            if int(self._slider.value) != index:
                self._slider.value = index
            bar = (t.direction, key)
            if self._fluid_bar_of != bar:  # the scale changes with the probe and the quantity only
                self._fluid_bar.image = colorbar_image(
                    self._fluid_vmax[key], f"probe {t.direction}: {self._fluid_by.value}"
                )
                self._fluid_bar_of = bar
            self._fluid_note.content = (
                f"probe {t.direction}: t = {t.steps[index] * t.dt:.3f} s (step "
                f"{t.steps[index]} of {self.data.steps}), {len(x):,} particles"
            )

    def set_playing(self, playing: bool) -> None:
        """Start or pause the replay."""
        self._playing = bool(playing) and self._trajectory is not None
        self._play.label = "Pause" if self._playing else "Play"

    def _play_loop(self) -> None:
        while not self._stop.wait(1.0 / self.options.fps):
            if self._playing and self._trajectory is not None:
                self.show_frame((self._frame + 1) % self._trajectory.num_frames)

    # ---- cameras ---------------------------------------------------------------------------------
    def _add_cameras(self) -> None:
        if not self.views:
            return
        gui, scene = self.server.gui, self.server.scene
        scored = [v for v in self.views if v.score is not None]
        values = np.array([v.score for v in scored])
        colors = score_colors(values) if scored else np.zeros((0, 3), np.uint8)
        color_of = {v.index: tuple(int(c) for c in col) for v, col in zip(scored, colors, strict=True)}
        size = 0.05 * self._extent
        for v in self.views:
            frustum = scene.add_camera_frustum(
                f"/cameras/{v.index:03d}",
                fov=v.fov_y,
                aspect=v.aspect,
                scale=size,
                thickness=0.06 * size,
                color=color_of.get(v.index, (60, 60, 60)),
                wxyz=v.wxyz,
                position=v.position,
            )
            frustum.on_click(lambda event, v=v: self.go_to(event.client, v))
            self._frustums.append(frustum)
            if v.rank is not None:
                scene.add_label(f"/cameras/{v.index:03d}/rank", f"#{v.rank}", position=(0.0, 0.0, 0.0))
        ranked = sorted(scored, key=lambda v: v.rank)
        with gui.add_folder("Cameras"):
            show = gui.add_checkbox(f"cameras ({len(self.views)})", True)
            options = ["-", *(self._view_label(v) for v in (ranked or self.views))]
            goto = gui.add_dropdown(
                "go to view",
                options,
                initial_value="-",
                hint="move the viewport to a candidate camera (or click its frustum)",
            )
            if ranked:
                gui.add_image(
                    colorbar_image(float(values.max()), "view score S(T) of the frustums", vmin=float(values.min())),
                    format="png",
                )
            if any(v.uncertainty_png is not None for v in self.views):
                self._uncertainty = gui.add_image(
                    np.full((8, 8, 3), 255, np.uint8), format="png", label="composited D_g of the view", visible=False
                )
        by_label = {self._view_label(v): v for v in self.views}

        def show_cameras(_) -> None:
            for frustum in self._frustums:
                frustum.visible = show.value

        def go_to_chosen(event) -> None:
            view = by_label.get(goto.value)
            if view is not None and event.client is not None:
                self.go_to(event.client, view)
                goto.value = "-"  # so that choosing the same view again moves there again

        show.on_update(show_cameras)
        goto.on_update(go_to_chosen)

    def ranked_views(self) -> list[CandidateView]:
        """The scored views, best first, at most TOP_VIEWS."""
        return sorted((v for v in self.views if v.rank is not None), key=lambda v: v.rank)[:TOP_VIEWS]

    @staticmethod
    def view_caption(v: CandidateView) -> str:
        """``S = ...`` and, when scores.json has them, the coverage ``A`` and ``S/A`` (physics_mean), to two
        significant digits as ``fluidgs score`` prints them."""
        parts = [f"S = {_two_digits(v.score)}"]
        if v.coverage is not None:
            parts.append(f"A = {_two_digits(v.coverage)}")
        if v.physics_mean is not None:
            parts.append(f"S/A = {_two_digits(v.physics_mean)}")
        return ", ".join(parts)

    def _add_view_list(self) -> None:
        """The side panel's list of the top views: per view a button (rank and name; a click moves the viewport
        there), its numbers and a thumbnail."""
        ranked = self.ranked_views()
        self._view_buttons: list = []
        self._view_images: list = []
        if not ranked:
            return
        gui = self.server.gui
        rgb, _ = self.splat_colors("D_g max")
        with gui.add_folder(f"Top views ({len(ranked)} of {len(self.views)})"):
            gui.add_markdown("ranked by S(T); a click moves the view there")
            for v in ranked:
                button = gui.add_button(f"#{v.rank} {v.name}", hint=f"camera {v.index}: {self.view_caption(v)}")
                button.on_click(lambda event, v=v: self._clicked(event, v))
                image = gui.add_image(
                    view_thumbnail(v, self.data.means, rgb), label=self.view_caption(v), format="jpeg", jpeg_quality=85
                )
                self._view_buttons.append(button)
                self._view_images.append(image)

    def _clicked(self, event, view: CandidateView) -> None:
        if event.client is not None:  # a click from a browser (not from the server's own code)
            self.go_to(event.client, view)

    @staticmethod
    def _view_label(v: CandidateView) -> str:
        """'#rank name (S = .., A = .., S/A = ..)': the score and its parts, to two significant digits."""
        if v.rank is None:
            return f"{v.index}: {v.name}"
        parts = "".join(
            f", {k} = {_two_digits(x)}" for k, x in (("A", v.coverage), ("S/A", v.physics_mean)) if x is not None
        )
        return f"#{v.rank} {v.name} (S = {_two_digits(v.score)}{parts})"

    def go_to(self, client, view: CandidateView) -> None:
        """Move ``client``'s viewport to ``view``: its centre, direction and vertical field of view."""
        distance = max(float(np.linalg.norm(self._centre - view.position)), 1e-3)
        with client.atomic():
            client.camera.fov = view.fov_y
            client.camera.wxyz = view.wxyz
            client.camera.position = view.position
            client.camera.look_at = view.position + view.forward * distance
        log.info(
            "view moved to camera %d %s%s",
            view.index,
            view.name,
            "" if view.rank is None else f" (rank {view.rank}, S = {_two_digits(view.score)})",
        )
        self._show_uncertainty(view)

    def _show_uncertainty(self, view: CandidateView) -> None:
        """Show the view's physics-uncertainty picture (composited D_g, with its scale bar) in the Cameras panel."""
        handle = self._uncertainty
        if handle is None:
            return
        if view.uncertainty_png is None:
            handle.visible = False
            return
        import cv2  # noqa: PLC0415 - only when a picture is shown

        picture = cv2.imread(str(view.uncertainty_png), cv2.IMREAD_COLOR)
        if picture is None:
            handle.visible = False
            return
        handle.image = picture[:, :, ::-1].copy()
        handle.visible = True

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
    if not _is_loopback(options.host):
        log.warning(
            "serving on %s: anyone who can reach this machine on port %d can open the viewer",
            options.host,
            options.port,
        )
    return FluidViewer(data, looks, views, options)


def serve(viewer: FluidViewer, announce=log.info) -> int:
    """Announce the URL (``announce(line)``; `fluidgs view` prints it), serve until Ctrl-C (or SIGTERM), stop
    cleanly; returns 0."""

    def on_term(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, on_term) if threading.current_thread() is threading.main_thread() else None
    try:  # the URL is announced inside: a Ctrl-C right after it (on a loaded machine) also stops cleanly
        announce(f"fluidgs view: {viewer.url} (Ctrl-C stops)")
        viewer.wait()
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    log.info("viewer stopped")
    return 0
