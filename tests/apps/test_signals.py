"""Signals end everything a command started and leave nothing behind (apps.signals).

Real signals (os.kill) reach the commands at chosen points (inside the final write, between two outputs, twice) in
this process, and at random moments in subprocesses; every output is then complete and valid, or absent, no
``.fgs-*.tmp`` stays, the exit code is 130 for SIGINT and 143 for SIGTERM, and no worker process outlives its parent.
"""

import importlib.util
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import pytest
import torch

from apps import cli
from fluidsim.files import TEMP_NAME, PendingFile, check_writable, remove_stale_temps, remove_unfinished
from recon.formats.ply import save_gaussians
from recon.gaussians import GaussianSet

from helpers.paths import REPO
from helpers.scenes import small_scene
from helpers.spheres import sphere_gaussians

FAST = ["--particle-radius", "0.08", "--steps", "12", "--dt", "0.004", "--no-empty-reference", "--threads", "2"]


def _scene(**over) -> dict:
    return small_scene(**{"steps": 4, **over})


def leftovers(folder: Path) -> list[Path]:
    return [p for p in Path(folder).rglob("*") if TEMP_NAME.match(p.name)]


@pytest.fixture(scope="module")
def sphere(tmp_path_factory):
    return save_gaussians(sphere_gaussians(), tmp_path_factory.mktemp("signals") / "sphere.ply")


@pytest.fixture
def kill_at_commit(monkeypatch):
    """``arm(name, times, sig)``: the commit of the ``name`` output sends ``sig`` to this process ``times`` times
    just before its rename (inside the final write)."""
    real = PendingFile.commit

    def arm(name: str, times: int = 1, sig: int = signal.SIGTERM):
        def commit(self):
            if self.path.name == name:
                for _ in range(times):
                    os.kill(os.getpid(), sig)
            return real(self)

        monkeypatch.setattr(PendingFile, "commit", commit)

    return arm


# ---- signals at chosen points, in this process --------------------------------------------------------------------
@pytest.mark.parametrize("times", [1, 2])
def test_sigterm_in_the_final_write_of_simulate(sphere, tmp_path, kill_at_commit, caplog, times):
    """SIGTERM (once, or twice: the second is ignored while cleaning up) inside the rename of RESULT.h5: exit 143,
    no RESULT.h5, no .ply, no temporary file; SIGINT gives 130."""
    kill_at_commit("r.h5", times)
    assert cli.main(["simulate", str(sphere), "-o", str(tmp_path / "r.h5"), "--directions=-x", *FAST]) == 143
    assert "interrupted by SIGTERM" in caplog.text
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    kill_at_commit("r.h5", 1, signal.SIGINT)
    assert cli.main(["simulate", str(sphere), "-o", str(tmp_path / "r.h5"), "--directions=-x", *FAST]) == 130
    assert not list(tmp_path.iterdir())


def test_sighup_is_handled_like_sigterm_unless_ignored(sphere, tmp_path, kill_at_commit, caplog):
    """A closed terminal (SIGHUP) in the final write: exit 129, nothing left; under nohup (SIGHUP ignored when the
    command starts) it stays ignored and the command completes."""
    from apps.signals import handled_signals

    kill_at_commit("r.h5", 1, signal.SIGHUP)
    assert cli.main(["simulate", str(sphere), "-o", str(tmp_path / "r.h5"), "--directions=-x", *FAST]) == 129
    assert "interrupted by SIGHUP" in caplog.text and not list(tmp_path.iterdir())
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        assert signal.SIGHUP not in handled_signals()
        assert cli.main(["simulate", str(sphere), "-o", str(tmp_path / "r.h5"), "--directions=-x", *FAST]) == 0
        assert signal.getsignal(signal.SIGHUP) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, previous)
    assert (tmp_path / "r.h5").is_file()


def test_sigterm_between_two_outputs_keeps_the_first_complete(sphere, tmp_path, kill_at_commit):
    from nbv.physics import load_result

    kill_at_commit("r_divergence.ply")
    assert cli.main(["simulate", str(sphere), "-o", str(tmp_path / "r.h5"), "--directions=-x", *FAST]) == 143
    assert load_result(tmp_path / "r.h5").dbar >= 0  # complete and valid
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.h5"]


def test_sigterm_in_the_final_write_of_sweep(sphere, tmp_path, kill_at_commit):
    kill_at_commit("s.png", 2)
    args = [
        "sweep",
        str(sphere),
        "--velocities",
        "3",
        "--directions=-x",
        "-o",
        str(tmp_path / "s.csv"),
        *[a for a in FAST if a != "--no-empty-reference"],
    ]
    assert cli.main(args) == 143
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.csv"]  # the CSV was written before the plot
    assert (tmp_path / "s.csv").read_text().count("\n") == 2


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_sim_signal_twice_in_the_final_write(tmp_path, kill_at_commit, sig, code):
    """A signal inside the final write of `sim` lets the write finish (the file is complete: exit 128 + signal);
    two signals drop the unfinished file: nothing is left, and the exit code is that of the signal."""
    (tmp_path / "scene.json").write_text(json.dumps(_scene()))
    out = tmp_path / "out.h5"
    kill_at_commit("out.h5", 1, sig)
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(out), "--threads", "2"]) == code
    with h5py.File(out) as f:
        assert f.attrs["status"] == "complete"
    out.unlink()
    kill_at_commit("out.h5", 2, sig)
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(out), "--threads", "2"]) == code
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.json"]


def test_interrupted_rerun_of_sim_keeps_the_complete_file(tmp_path, monkeypatch, caplog):
    """Ctrl-C on a re-run: the earlier complete OUT.h5 stays, the partial run goes to OUT.interrupted.h5, named."""
    import fluidsim.recording

    (tmp_path / "scene.json").write_text(json.dumps(_scene(steps=6)))
    out = tmp_path / "out.h5"
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(out), "--threads", "2"]) == 0
    before = out.read_bytes()
    real_run = fluidsim.recording.run

    def run_with_ctrl_c(solver, steps, on_step, progress):
        def step(s, st):
            if st.step == 2:
                os.kill(os.getpid(), signal.SIGINT)
            on_step(s, st)

        return real_run(solver, steps, on_step=step, progress=progress)

    monkeypatch.setattr(fluidsim.recording, "run", run_with_ctrl_c)
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(out), "--threads", "2"]) == 130
    assert out.read_bytes() == before
    partial = tmp_path / "out.interrupted.h5"
    with h5py.File(partial) as f:
        assert f.attrs["status"] == "interrupted" and int(f.attrs["interrupted_after_step"]) == 3
    assert str(partial) in caplog.text and "is kept" in caplog.text
    assert not leftovers(tmp_path)


def test_a_refused_run_leaves_no_empty_folder(tmp_path, monkeypatch):
    import fluidsim.simulation

    (tmp_path / "scene.json").write_text(json.dumps(_scene()))

    def refuse(scene):
        raise ValueError("refused after the output check")

    monkeypatch.setattr(fluidsim.simulation, "build_solver", refuse)
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "a" / "b" / "out.h5")]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.json"]


def test_remove_unfinished_and_stale_temps(tmp_path):
    check_writable(tmp_path / "new" / "deeper" / "x.h5")
    (tmp_path / "keep").mkdir()
    pending = PendingFile(tmp_path / "keep" / "y.h5")
    pending.tmp.write_bytes(b"half")
    removed = remove_unfinished()
    assert pending.tmp in removed and not pending.tmp.exists()
    assert not (tmp_path / "new").exists() and (tmp_path / "keep").is_dir()  # only empty folders it made go
    (tmp_path / ".fgs-0123abcd.tmp").write_bytes(b"left by SIGKILL")
    (tmp_path / ".fgs-89abcdef.tmp.old").mkdir()
    (tmp_path / "fgs-0123abcd.tmp").write_bytes(b"not ours")
    assert len(remove_stale_temps(tmp_path)) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fgs-0123abcd.tmp", "keep"]


# ---- signals at random moments, in subprocesses -------------------------------------------------------------------
def _start(args: list[str], log: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "apps.cli", *args],
        stdout=subprocess.DEVNULL,
        stderr=open(log, "w"),
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        start_new_session=True,
    )


def _wait_for(log: Path, text: str, proc: subprocess.Popen, timeout: float = 120) -> None:
    t0 = time.monotonic()
    while text not in log.read_text():
        if proc.poll() is not None or time.monotonic() - t0 > timeout:
            proc.kill()
            raise AssertionError(f"never saw {text!r}: {log.read_text()[-2000:]}")
        time.sleep(0.05)


def test_simulate_stopped_at_random_moments_leaves_valid_outputs_or_none(sphere, tmp_path):
    """SIGTERM at random moments of the probes and the final writes (seeded): exit 143 (or 0 when the signal came
    after the end), and each output is complete and valid, or absent."""
    from nbv.physics import load_result
    from recon import load_gaussians

    rng = random.Random(7)
    for k in range(3):
        folder = tmp_path / f"run{k}"
        folder.mkdir()
        log = folder.parent / f"log{k}.txt"
        proc = _start(["simulate", str(sphere), "-o", str(folder / "r.h5"), "--directions=-x,+z", *FAST], log)
        _wait_for(log, "Taichi on", proc)
        time.sleep(rng.uniform(0.0, 4.0))
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=120)
        assert code in (0, 143), log.read_text()[-2000:]
        assert "Traceback" not in log.read_text()
        names = sorted(p.name for p in folder.iterdir())
        assert set(names) <= {"r.h5", "r_divergence.ply"} and not leftovers(folder), names
        if "r.h5" in names:
            assert load_result(folder / "r.h5").num_gaussians == 300
        if "r_divergence.ply" in names:
            assert load_gaussians(folder / "r_divergence.ply").num == 300


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_sim_second_signal_gives_the_first_signals_code(tmp_path, sig, code):
    block = {"min": [0.1, 0.1, 0.1], "max": [0.6, 0.6, 0.6], "velocity": [1, 0, 0]}
    (tmp_path / "scene.json").write_text(json.dumps(_scene(steps=100000, particle_radius=0.02, fluid_blocks=[block])))
    log = tmp_path / "log.txt"
    proc = _start(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "out.h5"), "--threads", "2"], log)
    _wait_for(log, "fluid particles", proc)
    time.sleep(1.0)
    proc.send_signal(sig)
    time.sleep(0.05)
    proc.send_signal(sig)
    assert proc.wait(timeout=120) == code, log.read_text()[-2000:]
    assert "Traceback" not in log.read_text()
    assert not leftovers(tmp_path)
    names = sorted(p.name for p in tmp_path.iterdir())
    if "out.h5" in names:  # the first signal's save finished before the second came
        with h5py.File(tmp_path / "out.h5") as f:
            assert f.attrs["status"] == "interrupted"


def _descendants(pid: int) -> set[int]:
    out, todo = set(), [pid]
    while todo:
        p = todo.pop()
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                children = (task / "children").read_text().split()
            except OSError:
                continue
            for c in map(int, children):
                if c not in out:
                    out.add(c)
                    todo.append(c)
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.parametrize("workers, sig", [(1, "term"), (2, "term"), ("ray", "term"), (2, "hup")])
def test_sigterm_on_experiment_ends_its_workers(tmp_path, workers, sig):
    """SIGTERM to `fluidgs experiment` (workers busy with their jobs): exit 143, and no worker process, resource
    tracker, Ray process or other child outlives the parent, nor keeps writing into the run folders."""
    if workers == "ray" and importlib.util.find_spec("ray") is None:
        pytest.skip("Ray is not installed (optional extra: pip install -e .[ray])")
    from recon.mesh_render import MeshDatasetConfig, render_mesh_dataset

    from helpers.paths import TORUS

    scene = render_mesh_dataset(
        TORUS, tmp_path / "torus", MeshDatasetConfig(n_train=8, n_test=2, resolution=16, supersample=1), progress=False
    )
    active = {
        "budget": 3,
        "iterations_per_view": 2,
        "total_iterations": 100000,
        "resolution": 16,
        "backend": "torch",
        "train": {"init_points": 100, "sh_degree": 0, "max_gaussians": 200},
    }
    config = {
        "scenes": [str(scene)],
        "methods": ["random"],
        "seeds": [0, 1],
        "reference_views": None,
        "output": str(tmp_path / "out"),
        "active": active,
    }
    (tmp_path / "exp.json").write_text(json.dumps(config))
    log = tmp_path / "log.txt"
    executor = ["--executor", "ray"] if workers == "ray" else ["--workers", str(workers)]
    proc = _start(["experiment", str(tmp_path / "exp.json"), *executor, "--no-progress"], log)
    t0 = time.monotonic()
    while not list((tmp_path / "out" / "runs").rglob("rounds.json")) and time.monotonic() - t0 < 180:
        assert proc.poll() is None, log.read_text()[-2000:]
        time.sleep(0.2)
    time.sleep(1.0)
    children = _descendants(proc.pid)
    assert len(children) >= (workers if workers != "ray" else 2)
    if sig == "hup":  # a closed terminal: SIGHUP to the whole process group, workers included
        os.killpg(proc.pid, signal.SIGHUP)
    else:
        proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == (129 if sig == "hup" else 143), log.read_text()[-3000:]
    assert "Traceback" not in log.read_text(), log.read_text()[-6000:]
    deadline = time.monotonic() + 10
    while any(_alive(c) for c in children) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not [c for c in children if _alive(c)]
    assert not leftovers(tmp_path / "out")


def test_a_stop_signal_lost_in_a_weakref_callback_still_ends_with_its_code(tmp_path, monkeypatch, caplog):
    """A Ctrl-C whose Stopped is raised where Python only prints "Exception ignored" (h5py frees its objects in weakref
    callbacks) used to end the command with 0; the noted signal now gives 130, with one line."""
    import weakref

    import apps.inspect_gaussians
    from apps import signals

    class Thing:
        pass

    def swallowed(args):
        thing = Thing()
        weakref.finalize(thing, signals.handle, signal.SIGINT, None)  # raises Stopped inside the finalizer
        del thing  # ... which Python reports and ignores
        return 0

    monkeypatch.setattr(apps.inspect_gaussians, "run_command", swallowed)
    ply = tmp_path / "g.ply"
    save_gaussians(GaussianSet.from_points(torch.rand(20, 3), scale=0.05, opacity=0.9), ply)
    assert cli.main(["inspect", str(ply)]) == 130
    assert "interrupted by SIGINT" in caplog.text
