"""The former name of :mod:`fluidsim.estimator` (paper Eq. 1, the divergence estimate D_i), kept so that old
imports keep working. The DFSPH divergence-free solver is :mod:`fluidsim.dfsph`."""

from .estimator import divergence_estimate_from_gradients as estimate_divergence_from_gradients
from .estimator import divergence_estimate_from_grid as estimate_divergence_from_grid
from .estimator import divergence_estimate_from_lists as estimate_divergence_from_lists
from .estimator import divergence_estimate_np as divergence_np

__all__ = [
    "divergence_np",
    "estimate_divergence_from_gradients",
    "estimate_divergence_from_grid",
    "estimate_divergence_from_lists",
]
