"""The `fluidgs` command-line applications (one module per subcommand; :mod:`apps.cli` is the entry point).

torch's OpenMP threads wait at each parallel region's barrier. By default they spin there, and on a shared CPU a
spinning thread holds the core that its partner needs: with two threads on the loaded 2-core machine, training and
FisherRF ran 10-25 times slower than with one (docs/performance.md). The package therefore sets
``OMP_WAIT_POLICY=PASSIVE`` (waiting threads sleep) before any subcommand loads torch; the OpenMP runtime reads it
when torch loads it. Nothing is imported here, so `fluidgs --help` and `fluidgs sim` stay free of torch. A policy
the user sets is left alone. ``FLUIDGS_OMP_POLICY_SET`` marks that the policy is ours, so that the SPlisHSPlasH peer
of ``bench sim`` (:mod:`nbv.bench.splash`) runs with its own defaults.
"""

import os

if "OMP_WAIT_POLICY" not in os.environ:
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    os.environ["FLUIDGS_OMP_POLICY_SET"] = "1"
