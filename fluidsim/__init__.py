"""fluidsim: a Taichi DFSPH engine with uniform-grid neighbour search and an SPH divergence estimator.

Never imports torch. Only applications and test fixtures call ``ti.init``; this package uses the
runtime it finds (arrays are Taichi ndarrays, so kernels compile once per process).

Paper symbols and their names in the code:

=================  ===================================  ==========================================
symbol             meaning                              code
=================  ===================================  ==========================================
rho, rho_0         density, rest density                ``density`` (rho / rho_0), ``rest_density``
alpha              DFSPH factor                         ``factor`` (alpha_i / rho_i)
kappa              DFSPH stiffness                      ``stiffness`` (kappa_i / rho_i), ``kappa_*``
h                  SPH support radius                   ``support_radius`` (= 4 r by default)
r                  particle radius                      ``particle_radius``; spacing 2 r
V                  particle volume                      ``volume``, ``fluid_volume``
W, grad W          cubic spline kernel (Monaghan 1992)  ``cubic_w``, ``cubic_grad_w``
mu                 dynamic viscosity                    ``viscosity``
D_i                divergence magnitude (paper Eq. 1)   ``divergence``, ``divergence_sum/count``
h_r, h_k           estimator radius and kernel support  ``estimator_radius``, ``estimator_kernel_radius``
lambda             probe inflow speed                   ``ProbeConfig.speed``
=================  ===================================  ==========================================
"""

from .config import SolverConfig
from .probes import DIRECTIONS, ProbeConfig, ProbeSetup, probe_setup, run_probes
from .scene import Scene, SceneError, load_scene, parse_scene
from .simulation import SimulationDiverged, build_solver, run
from .solver import DFSPHSolver, StepStats

__all__ = [
    "DIRECTIONS", "DFSPHSolver", "ProbeConfig", "ProbeSetup", "Scene", "SceneError", "SimulationDiverged",
    "SolverConfig", "StepStats", "build_solver", "load_scene", "parse_scene", "probe_setup", "run", "run_probes",
]
