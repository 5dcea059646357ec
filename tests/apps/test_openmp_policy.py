"""apps loads torch with OpenMP's passive wait policy and leaves the environment as it found it."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import os
import apps
print(os.environ.get("OMP_WAIT_POLICY"))
"""


def _run(env_policy):
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    if env_policy is not None:
        env["OMP_WAIT_POLICY"] = env_policy
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True)
    return out.stdout.split()[-1]


def test_the_policy_is_removed_after_torch_loads_and_a_users_policy_is_kept():
    assert _run(None) == "None"  # child processes do not inherit it
    assert _run("ACTIVE") == "ACTIVE"
