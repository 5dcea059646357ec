"""The `fluidgs` command-line applications (one module per subcommand; :mod:`apps.cli` is the entry point).

torch's OpenMP threads wait at each parallel region's barrier. By default they spin there, and on a shared CPU a
spinning thread holds the core that its partner needs: with two threads on the loaded 2-core machine, training and
FisherRF ran 10-25 times slower than with one (docs/performance.md). The package therefore loads torch with
``OMP_WAIT_POLICY=PASSIVE`` (waiting threads sleep) before any subcommand does, and removes the variable again: the
OpenMP runtime reads it once, when torch loads it, and child processes (the SPlisHSPlasH peer of ``bench sim``) keep
their own defaults. A policy the user sets is left alone.
"""

import os

if "OMP_WAIT_POLICY" not in os.environ:
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    try:
        import torch  # noqa: F401 (loads the OpenMP runtime under the policy)
    finally:
        del os.environ["OMP_WAIT_POLICY"]
