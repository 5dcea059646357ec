"""nbv.camera_shares: shares of the cameras in forked processes on Linux give what threads give, and a child's
failure reaches the caller."""

from __future__ import annotations

import os
import signal
import sys

import pytest
import torch

from nbv import camera_shares as cs

linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="forked shares run on Linux only")


def _share_work(ks: range) -> tuple[dict, torch.Tensor, int]:
    seen = torch.zeros(10, dtype=torch.float64)
    seen[list(ks)] = 1.0
    return {k: float(k) ** 0.5 for k in ks}, seen, os.getpid()


@linux_only
def test_forked_shares_equal_threaded_ones_and_run_elsewhere(monkeypatch):
    forked = cs.camera_shares(_share_work, 10, 3, "t", pairs=cs.FORK_MIN_PAIRS)
    monkeypatch.setenv(cs.PROCESSES_ENV, "0")
    threaded = cs.camera_shares(_share_work, 10, 3, "t", pairs=cs.FORK_MIN_PAIRS)
    for (a, sa, _), (b, sb, pb) in zip(forked, threaded, strict=True):
        assert a == b and torch.equal(sa, sb) and pb == os.getpid()
    assert forked[0][2] == os.getpid() and len({p for *_, p in forked}) == 3  # the first share here, two children
    assert [sorted(part[0]) for part in forked] == [[0, 3, 6, 9], [1, 4, 7], [2, 5, 8]]


def test_small_work_and_other_platforms_use_threads(monkeypatch):
    small = cs.camera_shares(_share_work, 4, 2, "t", pairs=cs.FORK_MIN_PAIRS - 1)
    assert {p for *_, p in small} == {os.getpid()}
    monkeypatch.setattr(cs.sys, "platform", "darwin")
    assert not cs.forking()
    large = cs.camera_shares(_share_work, 4, 2, "t", pairs=cs.FORK_MIN_PAIRS)
    assert {p for *_, p in large} == {os.getpid()}


def _fails_in_child(ks: range):
    if 1 in ks and os.getpid() != _PARENT[0]:
        raise ValueError(f"camera {ks[0]} cannot be scored")
    return {k: k for k in ks}


def _dies_in_child(ks: range):
    if os.getpid() != _PARENT[0]:
        os.kill(os.getpid(), signal.SIGKILL)
    return {k: k for k in ks}


_PARENT = [os.getpid()]


@linux_only
def test_a_childs_exception_and_death_reach_the_caller():
    _PARENT[0] = os.getpid()
    with pytest.raises(ValueError, match="camera 1 cannot be scored"):
        cs.camera_shares(_fails_in_child, 4, 2, "t", pairs=cs.FORK_MIN_PAIRS)
    with pytest.raises(RuntimeError, match=r"without its result \(killed by signal 9.*FLUIDGS_SCORING_PROCESSES=0"):
        cs.camera_shares(_dies_in_child, 4, 2, "t", pairs=cs.FORK_MIN_PAIRS)


@linux_only
def test_a_killed_parent_leaves_no_child(tmp_path):
    """The child dies with its parent (PR_SET_PDEATHSIG): a SIGKILLed command leaves nothing scoring on."""
    import subprocess
    import time

    pids = tmp_path / "child.pid"
    script = f"""
import os, time
from nbv import camera_shares as cs
def work(ks):
    if 1 in ks:
        open({str(pids)!r}, "w").write(str(os.getpid()))
    time.sleep(60)
cs.camera_shares(work, 2, 2, "t", pairs=cs.FORK_MIN_PAIRS)
"""
    parent = subprocess.Popen([sys.executable, "-c", script], cwd=os.getcwd())
    try:
        deadline = time.monotonic() + 60
        while not (pids.exists() and pids.read_text()) and time.monotonic() < deadline:
            time.sleep(0.05)
        child = int(pids.read_text())
    finally:
        parent.kill()
        parent.wait()

    def running() -> bool:  # a zombie waiting for a reaper (PID 1 of a container may not reap) has ended
        try:
            with open(f"/proc/{child}/stat") as stat:
                return stat.read().rsplit(")", 1)[1].split()[0] != "Z"
        except FileNotFoundError:
            return False

    deadline = time.monotonic() + 10
    while running() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not running()
