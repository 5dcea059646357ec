"""The viewer's solid and fluid panels: the solid particles the probes flowed against, the fluid particles left
inside the filled solid at a probe's end (leaks), and one probe's fluid replayed over time from its recorded
trajectory (:func:`viz.data.load_trajectory`), coloured by D_i (paper Eq. 1) or by speed on a scale fixed per
trajectory (the 99th percentile over its frames), with play/pause and a frame slider.

:class:`FluidPanel` is a part of :class:`viz.viewer.FluidViewer`, which supplies the viser server, RESULT.h5's arrays,
the options, the lock and the stop event, and calls :meth:`FluidPanel._add_solid` and :meth:`FluidPanel._add_fluid`
once while it builds the page.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

import numpy as np

from .colors import color_scale, colorbar_image, turbo
from .data import Trajectory, ViewData, load_trajectory, no_trajectory_message
from .serving import ViewerOptions

log = logging.getLogger("viz.viewer")  # the viewer's one logger, whichever of its modules writes the line

FLUID_VALUES = {"D_i, 1/s": "divergence", "speed, m/s": "speed"}
SOLID_RGB = (150, 150, 150)
LEAK_RGB = (255, 0, 255)
# values sampled to pick a trajectory's colour scale (the 99th percentile over all its frames)
SCALE_SAMPLES = 2_000_000


class FluidPanel:
    """The solid, the leaks and the replay of one probe's fluid (the methods of :class:`viz.viewer.FluidViewer` that
    draw them)."""

    server: Any  # viser.ViserServer
    data: ViewData
    options: ViewerOptions
    _lock: threading.RLock
    _stop: threading.Event
    _trajectory: Trajectory | None

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
