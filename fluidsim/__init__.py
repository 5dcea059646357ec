"""fluidsim: a Taichi DFSPH engine with uniform-grid neighbour search and an SPH divergence estimator.

Never imports torch. Only applications and test fixtures call ``ti.init``; this package uses the
runtime it finds (arrays are Taichi ndarrays, so kernels compile once per process).

Paper symbols and their names in the code (Bender & Koschier's DFSPH and FluidGaussian Eq. 1; the equations
that use them are in :mod:`fluidsim.solver`'s docstring, with the pass that computes each line of Algorithm 1):

=================  ===================================  ==========================================
symbol             meaning                              code
=================  ===================================  ==========================================
rho, rho_0         density, rest density                ``density`` (rho / rho_0), ``rest_density``
alpha              DFSPH factor                         ``factor`` (alpha_i / rho_i)
kappa              DFSPH stiffness (stored, warm start) ``kappa_divergence``, ``kappa_density``
                                                        (kappa_i / rho_i, per solver)
k_i                a solver iteration's stiffness       ``position_stiffness`` (the record (x_i, k_i)),
                   kappa_i / rho_i                      summed in ``stiffness_sum``
s_i                divergence-free solver's source      ``source`` (also the density solver's
                   D(rho_i / rho_0)/Dt, 1/s             error max(rho*_i - 1, 0) in its passes)
w_i                density solver's warm-start          ``density_record`` (the record (x_i, w_i))
                   stiffness (kappa_i where compressing)
P_i                a warm start's velocity push         ``push_divergence`` (divergence solver)
c_ij               V_j grad W_ij = c_ij (x_i - x_j)     ``fluid_pairs``, ``boundary_pairs`` (packed
                                                        (j, c_ij): ``fluid_pair``, ``unpack_pair``)
g_ij               V_j grad W(x_i - x_j, h)             rebuilt from c_ij in every list pass
G_i                sum_j g_ij + sum_b g_ib              ``grad_sum``; the boundary part
                                                        ``boundary_grad_sum``
h                  SPH support radius                   ``support_radius`` (= 4 r by default)
r                  particle radius                      ``particle_radius``; spacing 2 r
V                  particle volume                      ``volume`` (Akinci, boundary), ``fluid_volume``
W, grad W          cubic spline kernel (Monaghan 1992)  ``cubic_w``, ``cubic_grad_w``
mu                 dynamic viscosity                    ``viscosity``, ``boundary_viscosity``
D_i                divergence estimate (paper Eq. 1),   ``divergence``, ``divergence_sum/count``
                   apart from the DFSPH solver's s_i    (:mod:`fluidsim.estimator`)
h_r, h_k           estimator radius and kernel support  ``estimator_radius``, ``estimator_kernel_radius``
lambda             probe inflow speed                   ``ProbeConfig.speed``
=================  ===================================  ==========================================

The modules follow the algorithm: :mod:`fluidsim.grid` (cells, counting sort), :mod:`fluidsim.neighbors`
(the neighbour walk ``for_each_neighbor``; lists, density, factor), :mod:`fluidsim.dfsph` (both pressure
solvers' passes), :mod:`fluidsim.viscosity` (non-pressure forces, v*), :mod:`fluidsim.estimator` (Eq. 1),
:mod:`fluidsim.passes` (one Python wrapper per pass) and :mod:`fluidsim.solver` (the time step).

Importing the package loads nothing: each public name is imported from its module on first use (PEP 562), so
the Taichi-free modules (:mod:`fluidsim.directions`, :mod:`fluidsim.config`) can be read by ``viz`` and by the
command-line help without starting the engine.
"""

from .lazy import lazy_exports

_EXPORTS = {
    "SolverConfig": "config",
    "DIRECTIONS": "directions",
    "ProbeConfig": "probes",
    "ProbeSetup": "probes",
    "probe_setup": "probes",
    "probe_setups": "probes",
    "run_probes": "probes",
    "Scene": "scene",
    "SceneError": "scene",
    "load_scene": "scene",
    "parse_scene": "scene",
    "SimulationDiverged": "faults",
    "build_solver": "simulation",
    "run": "simulation",
    "DFSPHSolver": "solver",
    "StepStats": "solver",
}
__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
