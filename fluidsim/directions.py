"""The names of the five fluid probes of the paper (Sec. 3.2, Fig. 3), defined once for every package.

``-x``, ``+x``, ``-z``, ``+z``: a slab flowing along that direction; ``-y``: a slab falling under gravity (Y-up).
The probes themselves are :mod:`fluidsim.probes`. This module imports nothing, so the Taichi-free packages
(``viz``) and the command-line help read the names without loading the engine.
"""

DIRECTIONS: tuple[str, ...] = ("-x", "+x", "-z", "+z", "-y")

__all__ = ["DIRECTIONS"]
