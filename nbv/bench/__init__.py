"""Measurement support of ``fluidgs bench`` and of the studies: code that measures the method, never part of it.

No paper equation is implemented here. The commands are in :mod:`apps.bench`; what they need beyond the method lives
here, one module per benchmark:

=========================  =====================================================  ===============================
module                     what                                                   used by
=========================  =====================================================  ===============================
:mod:`.splash`             the SPlisHSPlasH peer scene and its child process      ``bench sim``
:mod:`.splash_worker`      the child process (the only importer of pysplishsplash)  :mod:`.splash`
:mod:`.holes`              a hole punched in a capture; the solid and rim's D_g    ``bench hole``
:mod:`.score_agreement`    projection scores against full renders                 ``bench views``
:mod:`.dense_sets`         denser copies of a Gaussian set (jittered)             ``bench score``, ``bench views``
:mod:`.probe_profile`      a probe run profiled; stop rules judged against it     ``bench probes``
:mod:`.probe_timing`       probes on a set timed: simulation vs aggregation       ``bench score``
=========================  =====================================================  ===============================

Importing the package loads nothing but :func:`timed`, the benchmarks' one stopwatch; each module is imported on its
own.
"""

import time


def timed(fn, *args, **kwargs):
    """(``fn(*args, **kwargs)``, its wall seconds, its process CPU seconds); the wall clock is read innermost."""
    cpu, wall = time.process_time(), time.perf_counter()
    out = fn(*args, **kwargs)
    wall = time.perf_counter() - wall
    return out, wall, time.process_time() - cpu
