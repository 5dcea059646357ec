"""apps sets OpenMP's passive wait policy for torch without importing it, keeps a user's policy, and the
SPlisHSPlasH peer of bench sim runs with its own defaults."""

import os
import subprocess
import sys

from helpers.paths import REPO

PROBE = """
import os, sys
import apps
print(os.environ.get("OMP_WAIT_POLICY"), os.environ.get("FLUIDGS_OMP_POLICY_SET"), "torch" in sys.modules)
"""


def _run(env_policy):
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "FLUIDGS_OMP_POLICY_SET")}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    if env_policy is not None:
        env["OMP_WAIT_POLICY"] = env_policy
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True)
    return out.stdout.split()[-3:]


def test_the_policy_is_passive_unless_the_user_set_one_and_torch_is_not_imported():
    assert _run(None) == ["PASSIVE", "1", "False"]
    assert _run("ACTIVE") == ["ACTIVE", "None", "False"]


def test_the_peer_does_not_inherit_our_policy(monkeypatch, tmp_path):
    from nbv.bench import splash

    seen = {}

    def fake_run(cmd, env=None, **kwargs):
        seen.update(env or {})
        raise subprocess.TimeoutExpired(cmd, 1)

    monkeypatch.setenv("OMP_WAIT_POLICY", "PASSIVE")
    monkeypatch.setenv("FLUIDGS_OMP_POLICY_SET", "1")
    monkeypatch.setattr(splash.subprocess, "run", fake_run)
    try:
        splash.run_splash(splash.PeerScene(), timeout_s=1)
    except Exception:
        pass
    assert seen, "the peer was not launched"
    assert "OMP_WAIT_POLICY" not in seen and "FLUIDGS_OMP_POLICY_SET" not in seen
