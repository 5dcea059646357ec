"""viz: `fluidgs view`, the browser viewer of a probe run (viser), and the project's other pictures: the particle
renderer of `fluidgs render-frames`, browser-playable H.264 video and the matplotlib charts.

The viewer shows a RESULT.h5 of `fluidgs simulate` against the Gaussians it was computed from, in the simulation frame
(metres, Y-up): the splats in their own colours or coloured by D_g (paper Eq. 2-3; max, mean or one probe),
the solid particles, one probe's fluid replayed over time (recorded with ``--record-probe``, coloured by D_i of
paper Eq. 1 or by speed), the candidate cameras coloured by their view score S(T) (paper Eq. 4) with their rank,
and the probes' leak counts. It reads files only (h5py, JSON, the Gaussian formats of :mod:`recon.formats`):
no Taichi, never a simulation. Every file is written atomically through :mod:`fluidsim.files`.

======================  ==========================================  ========================================
module                  what                                        main entry
======================  ==========================================  ========================================
:mod:`.data`            RESULT.h5 for the viewer, trajectories      :func:`load_view_data`, :func:`load_trajectory`
:mod:`.splats`          own colours and opacities, match check      :func:`splat_looks`
:mod:`.cameras`         candidate cameras in the sim frame, S(T)    :func:`candidate_views`
:mod:`.colors`          TURBO map and colour bars (nbv.heatmap's)   :func:`turbo`, :func:`colorbar_image`
:mod:`.viewer`          the viser page: Gaussians, probe table      :func:`open_viewer`, :class:`FluidViewer`
:mod:`.fluid_panel`     solid, leaks, the probe's fluid replayed    :class:`FluidPanel`
:mod:`.camera_panel`    candidate cameras, top views, go to one     :class:`CameraPanel`
:mod:`.serving`         options, address check, serve until Ctrl-C  :class:`ViewerOptions`, :func:`serve`
:mod:`.frames`          OUT.h5 as orthographic depth-sorted dots    :func:`render_frames`, :class:`FrameStyle`
:mod:`.video`           H.264 MP4 (yuv420p, faststart), atomic      :func:`write_mp4`, :func:`video_info`
:mod:`.plots`           sweep plot, bar charts (matplotlib, Agg)    :func:`plot_sweep`, :func:`bar_chart`
======================  ==========================================  ========================================
"""

from fluidsim.lazy import lazy_exports

# each name is imported from its module on first use (PEP 562): `import viz.colors` (the heat-maps of `fluidgs
# score`) loads neither the viewer (viser, scipy) nor h5py
_EXPORTS = {
    **dict.fromkeys(("ViewData", "load_trajectory", "load_view_data"), "data"),
    **dict.fromkeys(("ViewerOptions", "serve"), "serving"),
    **dict.fromkeys(("FluidViewer", "open_viewer"), "viewer"),
}
__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
