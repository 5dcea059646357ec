"""The viewer's camera panels: the candidate cameras as frustums coloured by their view score S(T) (paper Eq. 4) with
their rank, a dropdown and a click that move the viewport to one, the physics-uncertainty picture of the chosen view
(when scores.json has one), and the side panel's list of the top views with their numbers and thumbnails.

:class:`CameraPanel` is a part of :class:`viz.viewer.FluidViewer`, which supplies the viser server, the candidate
views, the object's centre and size and the splat colours, and calls :meth:`CameraPanel._add_cameras` and
:meth:`CameraPanel._add_view_list` once while it builds the page.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from .cameras import CandidateView
from .colors import colorbar_image, score_colors
from .data import ViewData
from .thumbnails import view_thumbnail

log = logging.getLogger("viz.viewer")  # the viewer's one logger, whichever of its modules writes the line

TOP_VIEWS = 10  # views in the list of the side panel


def _two_digits(value: float) -> str:
    """``value`` rounded to two significant digits, as ``fluidgs score`` prints it (360, 4.9)."""
    return f"{float(f'{value:.2g}'):g}"


class CameraPanel:
    """The candidate cameras, the move to one of them and the list of the top views (the methods of
    :class:`viz.viewer.FluidViewer` that draw them)."""

    server: Any  # viser.ViserServer
    data: ViewData
    views: list[CandidateView]
    _centre: np.ndarray
    _extent: float
    _frustums: list
    _uncertainty: Any

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
