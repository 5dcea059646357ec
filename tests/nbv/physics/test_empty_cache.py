"""The empty-scene cache (nbv.physics.empty_cache): the reference D_g from cached fluid is the same bits as the one
simulated, on any Gaussians; damaged entries are refused and rebuilt; an unwritable folder runs without a cache;
the folder stays within its bound."""

import logging
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from fluidsim.probes import probe_setups
from nbv import physics
from nbv.physics import PhysicsConfig, ProbePlan, empty_cache, empty_scene, empty_scene_probes, simulate_gaussians
from nbv.physics.aggregate import GaussianAccumulator
from nbv.physics.aggregate_reference import accumulate_reference
from nbv.physics.empty_cache import EmptyCache, EmptyReference, EmptySamples, cache_key
from nbv.physics.scene_frame import gaussian_arrays_in_sim
from nbv.physics.solidify import SolidifyConfig, gaussians_to_solid
from recon.gaussians import GaussianSet

from helpers.spheres import fibonacci_sphere

CFG = PhysicsConfig(particle_radius=0.08, steps=8, dt=0.004, directions=("-x", "-y"), scale=1.0)


def _sphere(n: int = 300, radius: float = 0.5, scale: float = 0.06, shift=(0.0, 0.0, 0.0)) -> GaussianSet:
    pts = radius * fibonacci_sphere(n) + np.asarray(shift)
    return GaussianSet.from_points(torch.tensor(pts, dtype=torch.float32), scale=scale, opacity=0.9)


@pytest.fixture(scope="module")
def scene():
    """The plan of CFG around a sphere, and two sets of Gaussians to accumulate onto: the sphere's and others."""
    g = _sphere()
    tr = physics.scene_transform(g, CFG)
    plan = ProbePlan.of(gaussians_to_solid(g, SolidifyConfig(spacing=0.16), tr).points, CFG)
    sets = []
    for gs in (g, _sphere(500, radius=0.3, scale=0.03, shift=(0.1, -0.2, 0.05))):
        means, _, _, radii = gaussian_arrays_in_sim(gs, tr)
        sets.append((means, 20.0 * np.asarray(radii, np.float64)))  # reaching the slabs
    return plan, sets


def _count_solvers(monkeypatch) -> list:
    built = []
    real = empty_scene.build_probe_solver

    def counted(*args, **kwargs):
        built.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(empty_scene, "build_probe_solver", counted)
    return built


def test_cached_reference_equals_the_simulated_one_on_any_gaussians(scene, tmp_path, monkeypatch):
    """First run: simulated and stored; later runs on other Gaussians: accumulated from the cache, no solver, the
    same bits as simulating them afresh."""
    plan, sets = scene
    store = EmptyCache(tmp_path, 2**30)
    built = _count_solvers(monkeypatch)
    first, _ = empty_scene_probes(plan, *sets[0], CFG, progress=False, reference=EmptyReference(store))
    assert len(built) == 2 and len(store.entries()) == 4  # per probe: the fluid, and its means on these Gaussians
    for means, reach in sets:
        fresh, _ = empty_scene_probes(plan, means, reach, CFG, progress=False)
        assert len(built) == 4
        cached, _ = empty_scene_probes(plan, means, reach, CFG, progress=False, reference=EmptyReference(store))
        assert len(built) == 4  # no solver ran
        np.testing.assert_array_equal(cached, fresh)
        assert (fresh != 0).any()
        built.clear()
        built.extend([1, 1])
    np.testing.assert_array_equal(first, empty_scene_probes(plan, *sets[0], CFG, progress=False)[0])


def test_samples_replayed_in_batches_equal_the_twin():
    """add_samples over steps of different sizes, batched and interleaved: the O(P G) twin's sums and counts."""
    rng = np.random.default_rng(3)
    centers = rng.uniform(-1, 1, (60, 3))
    reach = rng.uniform(0.05, 0.4, 60)
    counts = np.array([37, 0, 5, 60, 12, 40, 3])
    pos = rng.uniform(-1.1, 1.1, (counts.sum(), 3)).astype(np.float32)
    vals = rng.normal(0, 2, counts.sum()).astype(np.float32)
    acc = GaussianAccumulator.build(centers, reach, [-1, -1, -1], [1, 1, 1], batch_steps=3)
    acc.add_samples(pos, vals, counts)
    sums, n = accumulate_reference(centers, reach, pos.astype(np.float64), vals, [-1, -1, -1], [1, 1, 1])
    np.testing.assert_array_equal(acc.counts, n)
    np.testing.assert_allclose(acc.sums, sums, atol=1e-6 * max(counts.sum(), 1))
    with pytest.raises(ValueError, match="sum to"):
        acc.add_samples(pos, vals, counts[:-1])
    with pytest.raises(ValueError, match="values"):
        acc.add_samples(pos, vals.astype(np.float64), counts)


def _entries(plan, sets, tmp_path):
    """One probe simulated and stored: its fluid samples' entry and its means' entry (the smaller)."""
    store = EmptyCache(tmp_path, 2**30)
    cfg = PhysicsConfig(**{**CFG.to_dict(), "directions": ("-x",)})
    expected, _ = empty_scene_probes(plan, *sets[1], cfg, progress=False, reference=EmptyReference(store))
    means, samples = [p for _, p in sorted((size, p) for _, size, p in store.entries())]
    return store, cfg, expected, samples, means


@pytest.mark.parametrize(
    "kind, damage",
    [("samples", d) for d in ("flip", "truncate", "foreign", "magic", "pad")] + [("means", "flip"), ("means", "pad")],
)
def test_a_damaged_entry_is_refused_and_rebuilt(scene, tmp_path, monkeypatch, caplog, kind, damage):
    """A damaged fluid entry is simulated again; a damaged means entry is accumulated again from the fluid; either
    gives the same bits as before, with a warning naming the entry, and is rebuilt whole."""
    plan, sets = scene
    store, cfg, expected, samples, means = _entries(plan, sets, tmp_path)
    entry = samples if kind == "samples" else means
    if kind == "samples":
        means.unlink()  # the fluid itself is read
    data = bytearray(entry.read_bytes())
    if damage == "flip":  # one bit of the payload: without the hash, a wrong D_g
        data[-50] ^= 0x10
    elif damage == "truncate":
        data = data[: len(data) // 2]
    elif damage == "pad":
        data += b"\0" * 16
    elif damage == "magic":
        data[:8] = b"NOTEMPTY"
    else:  # another key's entry under this name: its header names the other key
        key = entry.name[: -len(empty_cache.SUFFIX)]
        data = bytearray(bytes(data).replace(key.encode(), b"f" * 64, 1))
    entry.write_bytes(bytes(data))
    built = _count_solvers(monkeypatch)
    with caplog.at_level(logging.WARNING, logger="nbv.physics.empty_cache"):
        again, _ = empty_scene_probes(plan, *sets[1], cfg, progress=False, reference=EmptyReference(store))
    assert len(built) == (1 if kind == "samples" else 0)  # simulated again, or accumulated again
    np.testing.assert_array_equal(again, expected)
    assert any("damaged" in r.getMessage() and str(entry) in r.getMessage() for r in caplog.records)
    assert len(store.entries()) == 2 and entry.read_bytes() != bytes(data)  # rebuilt whole
    built.clear()
    again, _ = empty_scene_probes(plan, *sets[1], cfg, progress=False, reference=EmptyReference(store))
    np.testing.assert_array_equal(again, expected)
    assert not built


@pytest.mark.parametrize("kind", ["zero", "fifo", "huge"])
def test_an_entry_that_is_not_a_bounded_regular_file_is_never_read(scene, tmp_path, monkeypatch, caplog, kind):
    """A link to /dev/zero (would exhaust memory), a FIFO (would hang every later run), a file larger than any entry
    the cache writes: refused by type and size before a byte is read, removed, and rebuilt."""
    plan, sets = scene
    store, cfg, expected, samples, means = _entries(plan, sets, tmp_path)
    means.unlink()
    samples.unlink()
    if kind == "zero":
        samples.symlink_to("/dev/zero")
    elif kind == "fifo":
        os.mkfifo(samples)
    else:
        with open(samples, "wb") as fh:
            fh.truncate(store.max_bytes + 1)  # sparse: nothing is written
    built = _count_solvers(monkeypatch)
    with caplog.at_level(logging.WARNING, logger="nbv.physics.empty_cache"):
        again, _ = empty_scene_probes(plan, *sets[1], cfg, progress=False, reference=EmptyReference(store))
    assert len(built) == 1
    np.testing.assert_array_equal(again, expected)
    assert any(str(samples) in r.getMessage() and "removed" in r.getMessage() for r in caplog.records)
    assert samples.is_file() and not samples.is_symlink()  # rebuilt as a regular entry


def test_a_poisoned_means_entry_with_a_recomputed_hash_is_refused(scene, tmp_path, monkeypatch, caplog):
    """Means x 1000 with a valid SHA-256 (anyone who can write the folder can recompute it): larger than any |D_i| of
    the samples they claim to average, so refused and accumulated again."""
    plan, sets = scene
    store, cfg, expected, samples, means = _entries(plan, sets, tmp_path)
    key, samples_key = (p.name[: -len(empty_cache.SUFFIX)] for p in (means, samples))
    stored = store.load_means(key, len(sets[1][0]), samples_key)
    assert stored is not None
    store._write(key, {"means": stored * 1000.0}, samples_key)  # a consistent forgery
    built = _count_solvers(monkeypatch)
    with caplog.at_level(logging.WARNING, logger="nbv.physics.empty_cache"):
        again, _ = empty_scene_probes(plan, *sets[1], cfg, progress=False, reference=EmptyReference(store))
    assert not built  # accumulated again from the samples, not simulated
    np.testing.assert_array_equal(again, expected)
    assert any("exceeds the largest |D_i|" in r.getMessage() for r in caplog.records)


def test_an_unwritable_folder_runs_without_the_cache_with_one_line(scene, tmp_path, caplog):
    plan, sets = scene
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    store = EmptyCache(blocker / "cache", 2**30)
    with caplog.at_level(logging.WARNING, logger="nbv.physics.empty_cache"):
        out, _ = empty_scene_probes(plan, *sets[0], CFG, progress=False, reference=EmptyReference(store))
    lines = [r for r in caplog.records if r.name == "nbv.physics.empty_cache"]
    assert (
        len(lines) == 1
        and "cannot be written" in lines[0].getMessage()
        and "without the cache" in lines[0].getMessage()
    )
    assert store.disabled
    np.testing.assert_array_equal(out, empty_scene_probes(plan, *sets[0], CFG, progress=False)[0])


def _fake(n: int) -> dict:
    return {"step_counts": np.array([n]), "positions": np.zeros((n, 3), np.float32), "values": np.zeros(n, np.float32)}


def test_the_folder_keeps_its_bound_least_recently_used_first(tmp_path):
    one = len(empty_cache._encode(_fake(1000), "a" * 64)[0]) + 8 + 16 * 1000
    store = EmptyCache(tmp_path, int(2.5 * one))
    now = 1_000_000.0
    for i, key in enumerate(("a" * 64, "b" * 64)):
        assert store.save(key, EmptySamples(**_fake(1000)))
        os.utime(store.path(key), (now + i, now + i))
    assert store.load("a" * 64) is not None  # a is used: b is now the least recently used
    assert store.save("c" * 64, EmptySamples(**_fake(1000)))
    assert {p.name[:1] for _, _, p in store.entries()} == {"a", "c"}
    assert sum(size for _, size, _ in store.entries()) <= store.max_bytes
    assert not store.save("d" * 64, EmptySamples(**_fake(4000)))  # larger than the bound: not stored
    assert not store.path("d" * 64).exists()
    stale = tmp_path / ".fgs-0123abcd.tmp"
    stale.write_bytes(b"x")
    os.utime(stale, (now, now))
    store.evict()
    assert not stale.exists()


def test_the_key_follows_the_fluid_not_the_gaussians(scene):
    plan, _ = scene
    scfg = CFG.solver_config()
    base = cache_key(plan.setups["-x"], scfg, 2, 8, 1)
    assert base == cache_key(plan.setups["-x"], scfg, 2, 8, 1)
    assert len({base, cache_key(plan.setups["-y"], scfg, 2, 8, 1), cache_key(plan.setups["-x"], scfg, 2, 9, 1)}) == 3
    assert base != cache_key(plan.setups["-x"], scfg, 3, 8, 1)
    assert base != cache_key(
        plan.setups["-x"], PhysicsConfig(**{**CFG.to_dict(), "precision": "f64"}).solver_config(), 2, 8, 1
    )
    assert base != cache_key(plan.setups["-x"], scfg, 2, 8, 2)


def test_the_folder_and_bound_come_from_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("FLUIDGS_CACHE_DIR", str(tmp_path / "c"))
    assert empty_cache.cache_folder() == tmp_path / "c"
    monkeypatch.delenv("FLUIDGS_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
    assert empty_cache.cache_folder() == tmp_path / "x" / "fluidgs"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert empty_cache.cache_folder() == empty_cache.Path.home() / ".cache" / "fluidgs"
    assert empty_cache.max_bytes_from_env() == 4 * 2**30
    monkeypatch.setenv("FLUIDGS_CACHE_MAX_GB", "0.5")
    assert empty_cache.max_bytes_from_env() == 2**29
    for bad in ("-1", "lots", "nan"):
        monkeypatch.setenv("FLUIDGS_CACHE_MAX_GB", bad)
        with pytest.raises(ValueError, match="FLUIDGS_CACHE_MAX_GB"):
            empty_cache.max_bytes_from_env()


def test_simulate_uses_the_cache_unless_told_not_to(monkeypatch, tmp_path):
    """A second simulate on other Gaussians accumulates the cached fluid: the same empty reference as without the
    cache; empty_cache=False stores nothing; a bad bound is refused before any probe."""
    monkeypatch.setenv("FLUIDGS_CACHE_DIR", str(tmp_path / "cache"))
    cfg = PhysicsConfig(particle_radius=0.08, steps=40, dt=0.004, directions=("-x",), empty_reference=True)
    g = _sphere()
    off = simulate_gaussians(g, PhysicsConfig(**{**cfg.to_dict(), "empty_cache": False}), progress=False)
    assert not (tmp_path / "cache").exists()
    on = simulate_gaussians(g, cfg, progress=False)
    assert len(list((tmp_path / "cache").glob("*.empty"))) == 2  # the fluid and its means
    built = _count_solvers(monkeypatch)
    again = simulate_gaussians(g, cfg, progress=False)
    assert not built  # the empty scene came from the cache (the probe builds its solver in fluidsim)
    for r in (on, again):
        np.testing.assert_array_equal(r.empty_per_probe, off.empty_per_probe)
        assert r.dbar_empty == off.dbar_empty
    assert (off.empty_per_probe != 0).any()
    monkeypatch.setenv("FLUIDGS_CACHE_MAX_GB", "-2")
    with pytest.raises(ValueError, match="FLUIDGS_CACHE_MAX_GB"):
        simulate_gaussians(g, cfg, progress=False)
    assert not built


def test_a_bad_bound_is_refused_by_the_command_line(monkeypatch, tmp_path, caplog):
    from apps import cli
    from recon.formats.ply import save_gaussians

    ply = save_gaussians(_sphere(), tmp_path / "g.ply")
    monkeypatch.setenv("FLUIDGS_CACHE_MAX_GB", "lots")
    argv = ["simulate", str(ply), "-o", str(tmp_path / "r.h5"), "--steps", "2", "--particle-radius", "0.08"]
    try:
        code = int(cli.main(argv) or 0)
    except SystemExit as exc:
        code = exc.code
    assert code == 2 and "FLUIDGS_CACHE_MAX_GB='lots'" in caplog.text
    assert not (tmp_path / "r.h5").exists()
    try:  # --no-cache does not read the bound
        code = int(cli.main([*argv, "--no-cache", "--no-empty-reference", "--dt", "0.004"]) or 0)
    except SystemExit as exc:
        code = exc.code
    assert code == 0


def test_slightly_moved_gaussians_reuse_the_empty_scene(monkeypatch, tmp_path, caplog):
    """Gaussians moved by one spacing (as between two rounds of the active loop) give another solid box but, snapped
    to the probes' grid, the same setups: the second run accumulates the first run's empty-scene fluid (counted as
    solver runs, not timed)."""
    monkeypatch.setenv("FLUIDGS_CACHE_DIR", str(tmp_path / "cache"))
    runs = []
    real = empty_scene.run_solver
    monkeypatch.setattr(empty_scene, "run_solver", lambda *a, **k: runs.append(1) or real(*a, **k))
    cfg = PhysicsConfig(
        particle_radius=0.05, steps=20, dt=0.002, directions=("-x",), scale=1.0, empty_reference=True, probe_snap=4
    )
    first, moved = _sphere(), _sphere(shift=(0.1, 0.0, 0.0))  # sides near +-0.6 m, inside a cell of the 0.4 m grid
    solids = [physics.RunFrame.of(g, cfg).solidify().points for g in (first, moved)]
    assert not np.array_equal(solids[0].max(0), solids[1].max(0))  # the solid's box moved ...
    unsnapped = [probe_setups(p, replace(cfg.probe_config(), snap=0), 0.1, cfg.directions) for p in solids]
    assert unsnapped[0] != unsnapped[1]  # ... which, unsnapped, gives other probes
    assert ProbePlan.of(solids[0], cfg).setups == ProbePlan.of(solids[1], cfg).setups
    assert PhysicsConfig.from_dict(cfg.to_dict()) == cfg and "probe_snap" not in PhysicsConfig().to_dict()
    with pytest.raises(ValueError, match="probe_snap"):
        PhysicsConfig(probe_snap=-1)
    a = simulate_gaussians(first, cfg, progress=False)
    assert len(runs) == 1  # the empty scene ran once (the probe with the solid runs in fluidsim.probes)
    with caplog.at_level(logging.INFO, logger="nbv.physics.empty_scene"):
        b = simulate_gaussians(moved, cfg, progress=False)
    assert len(runs) == 1  # ... and the moved Gaussians' run took it from the cache
    assert "empty-scene probe -x: the fluid from the cache" in caplog.text
    assert a.empty_per_probe.shape == b.empty_per_probe.shape == (1, len(b.means))  # accumulated onto its own


def test_the_code_key_digests_the_runner_not_the_probe_run(tmp_path):
    """A copy of the sources digests as the originals; a comment edited in the probe run (run.py) or in a fluidsim
    module the runner does not import leaves the key, one in the runner or in the solver changes it."""
    import shutil

    import fluidsim

    physics_dir = Path(empty_cache.__file__).parent
    shutil.copytree(physics_dir, tmp_path / "physics")
    shutil.copytree(Path(fluidsim.__file__).parent, tmp_path / "fluidsim")
    names = [n for n, _ in empty_cache.runner_sources()]
    assert "nbv/physics/empty_scene.py" in names and "fluidsim/solver.py" in names and "nbv/physics/run.py" not in names

    def copied() -> str:
        return empty_cache.code_digest(empty_cache.runner_sources(tmp_path / "physics", tmp_path / "fluidsim"))

    assert copied() == empty_cache.code_digest()
    for kept in ("physics/run.py", "physics/recorder.py", "fluidsim/recording.py", "fluidsim/memory.py"):
        with open(tmp_path / kept, "a") as fh:
            fh.write("# a comment\n")
        assert copied() == empty_cache.code_digest(), kept
    for changed in ("physics/empty_scene.py", "fluidsim/solver.py", "fluidsim/files/atomic.py"):
        before = copied()
        with open(tmp_path / changed, "a") as fh:
            fh.write("# a comment\n")
        assert copied() != before, changed
