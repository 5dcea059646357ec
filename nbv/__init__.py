"""nbv: physics-aware view selection for 3D Gaussians (FluidGaussian, Sec. 3.2-3.4).

Bridges ``recon`` (torch) and ``fluidsim`` (Taichi): Gaussians become a solid (:mod:`nbv.physics.solidify`), the five
fluid probes run against it (:mod:`nbv.physics`), per-particle divergence is aggregated onto Gaussians through a
grid (:mod:`nbv.physics.aggregate`, paper Eq. 2-3), and views are scored and ranked (:mod:`nbv.scores`, Eq. 4-5;
:func:`score_views` ranks a camera file's candidates, :mod:`nbv.view_scoring`).
Never calls ``ti.init``: the applications and the test fixtures own the Taichi runtime.

=================  ==========================================  ========================================
symbol             meaning                                     code
=================  ==========================================  ========================================
D_g^(IC), D_g      per-Gaussian divergence per probe, max      ``PhysicsResult.per_probe``, ``.divergence``
n, r_g             reach factor (3), largest principal radius  ``PhysicsConfig.n_radius``, ``max_radii``
w_g, S(T)          view weight (Eq. 5), view score (Eq. 4)     :func:`view_weights`, :func:`view_scores`
D-bar              (1/|G|) sum pi tr(Sigma_g)^2 D_g            :func:`geometry_divergence`, ``.dbar``
|P_g|, C(T)        distinct particles near g, critical score   ``distinct_counts``, :func:`critical_scores`
A(T), S/A          coverage sum w_g; physics part S(T) / A(T)  ``ProjectedScores.coverage``, ``.physics_mean``
=================  ==========================================  ========================================
"""

from fluidsim.lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(
        ("PhysicsConfig", "PhysicsResult", "ProbeDiverged", "load_result", "save_result", "simulate_gaussians"),
        "physics",
    ),
    **dict.fromkeys(
        (
            "DepthBuffer",
            "critical_scores",
            "critical_subset",
            "geometry_divergence",
            "projected_counts",
            "projected_view_scores",
            "rank",
            "unoccluded",
            "view_scores",
            "view_weights",
        ),
        "scores",
    ),
    **dict.fromkeys(("SweepPoint", "reynolds", "run_sweep", "schedule"), "study.sweep"),
    **dict.fromkeys(("coverage_line", "ranking_agreement", "view_parts"), "coverage"),
    "score_views": "view_scoring",
}
__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
