"""The active-reconstruction loop (nbv.active, `fluidgs active`): schedule, initial views, round logs, the time
split, resume."""

import json
import math
from pathlib import Path

import pytest
import torch

from nbv.active import PARTS, ActiveConfig, biased_initial_views, config_differences, run_active
from nbv.active.timing import round_timing, run_timing, timing_line, visual_name
from nbv.physics import PhysicsConfig
from recon.camera import Camera
from recon.formats import load_gaussians

from helpers.paths import TORUS
from helpers.training import tiny_active_config


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    """The torus rendered at 24 px: 8 candidate views, 3 test views."""
    from recon.mesh_render import MeshDatasetConfig, render_mesh_dataset

    out = tmp_path_factory.mktemp("active") / "torus"
    return render_mesh_dataset(
        TORUS, out, MeshDatasetConfig(n_train=8, n_test=3, resolution=24, supersample=1), progress=False
    )


def leftover_temp_files(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.name.endswith(".tmp")]


# ---- config and schedule -------------------------------------------------------------------------


def test_schedule_and_validation():
    cfg = ActiveConfig(budget=10, initial_count=2, iterations_per_view=100, total_iterations=30000)
    assert cfg.rounds() == [2, 3, 4, 5, 6, 7, 8, 9]  # eight selections reach the budget of 10
    assert cfg.schedule_iterations() == 100 * sum(range(2, 10))
    with pytest.raises(ValueError, match="total_iterations"):
        ActiveConfig(budget=10, iterations_per_view=100, total_iterations=1000)
    ActiveConfig(budget=10, iterations_per_view=100, total_iterations=1000, mode="reset")  # reset: no constraint
    with pytest.raises(ValueError, match="mode"):
        ActiveConfig(mode="restart")
    with pytest.raises(ValueError, match="initial_count"):
        ActiveConfig(budget=2, initial_count=3)
    with pytest.raises(ValueError, match="ActiveConfig.train"):
        ActiveConfig(train={"learning_rate": 1})
    assert ActiveConfig(initial_ids=(4, 1, 7)).initial_count == 3
    small = ActiveConfig.from_preset("cpu-small", method="fisher")
    assert small.resolution == 64 and small.physics.particle_radius == 0.05 and small.preset == "cpu-small"
    assert ActiveConfig.from_dict(json.loads(json.dumps(small.to_dict()))) == small


def test_biased_initial_views_pick_the_anchor_and_its_neighbours():
    # 12 cameras on a circle around the origin; the anchor +x is closest to camera 3 (placed at +x)
    angles = [2 * math.pi * (k - 3) / 12 for k in range(12)]
    cams = [Camera.look_at([4 * math.cos(a), 0.3, 4 * math.sin(a)], [0, 0, 0], [0, 1, 0], 16, 16, 0.9) for a in angles]
    ids = biased_initial_views(cams, 3, direction=(1.0, 0.0, 0.0))
    assert ids[0] == 3 and set(ids[1:]) == {2, 4}  # the two circle neighbours of camera 3
    assert biased_initial_views(cams, 2, seed=5) == biased_initial_views(cams, 2, seed=5)
    firsts = {biased_initial_views(cams, 1, seed=s)[0] for s in range(8)}
    assert len(firsts) > 1  # the seed moves the anchor
    with pytest.raises(ValueError, match="count"):
        biased_initial_views(cams, 13)


def test_config_differences_names_nested_keys():
    assert config_differences({"a": 1, "b": {"c": 2, "d": 3}}, {"a": 1, "b": {"c": 5, "d": 3}, "e": 0}) == ["b.c", "e"]


# ---- the loop ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def straight_run(tiny_dataset, tmp_path_factory):
    """An uninterrupted random-planner run: budget 5 from views 0 and 1 (three selections)."""
    run = tmp_path_factory.mktemp("straight") / "run"
    cfg = tiny_active_config(budget=5, initial_ids=(0, 1))
    return cfg, run, run_active(tiny_dataset, run, cfg, progress=False)


def test_reach_replays_the_rounds_in_memory(straight_run, tiny_dataset, tmp_path, monkeypatch):
    """ActiveRun.reach, without a run folder: the run's picks up to a state, and that round's context."""
    from nbv.active import ActiveRun

    cfg, _, rounds = straight_run
    monkeypatch.chdir(tmp_path)
    active = ActiveRun(tiny_dataset, None, cfg, progress=False)
    reached = active.reach(4)
    assert reached.round == 2 and reached.selected == rounds["selected"][:4]
    assert reached.context.candidate_ids == rounds["rounds"][2]["candidates"]
    assert reached.trainer.iteration == (2 + 3 + 4) * cfg.iterations_per_view  # continue mode
    assert active.reach(3, picks=rounds["selected"]).selected == rounds["selected"][:3]  # known picks
    assert list(tmp_path.iterdir()) == []  # nothing written
    with pytest.raises(ValueError, match="needs a run folder"):
        active.run()
    with pytest.raises(ValueError, match="not a round"):
        active.reach(5)


def test_round_log_and_outputs(straight_run):
    cfg, run, rounds = straight_run
    logged = json.loads((run / "rounds.json").read_text())
    assert logged == rounds
    assert logged["selected"][:2] == [0, 1] and len(logged["selected"]) == 5 == len(set(logged["selected"]))
    assert len(logged["rounds"]) == 3
    for r, rec in enumerate(logged["rounds"]):
        before = logged["selected"][: 2 + r]
        assert rec["round"] == r and rec["n_selected"] == 2 + r
        assert rec["training"]["iterations"] == (2 + r) * cfg.iterations_per_view
        assert sorted(rec["candidates"] + before) == list(range(8))  # the candidates are the unselected views
        assert rec["pick"] in rec["candidates"] and rec["pick"] == logged["selected"][2 + r]
        assert rec["shortlist"] == rec["candidates"] and rec["k"] is None  # random: every candidate considered
        assert set(rec["scores"]) >= {"visual"} and set(rec["scores"]["visual"]) == {str(i) for i in rec["candidates"]}
    assert logged["final"]["iterations"] == cfg.total_iterations
    _check_timing(logged)
    g = load_gaussians(run / "gaussians.ply")
    assert g.num == logged["final"]["num_gaussians"]
    assert json.loads((run / "config.json").read_text())["active"]["method"] == "random"
    assert not leftover_temp_files(run)


def test_resume_after_interruption_equals_uninterrupted_run(tiny_dataset, straight_run, tmp_path):
    cfg, straight_dir, straight = straight_run

    class Interrupt(Exception):
        pass

    def stop_after_second(record):
        if record["round"] == 1:
            raise Interrupt

    with pytest.raises(Interrupt):
        run_active(tiny_dataset, tmp_path / "resumed", cfg, on_round=stop_after_second, progress=False)
    partial = json.loads((tmp_path / "resumed" / "rounds.json").read_text())
    assert len(partial["rounds"]) == 2 and "final" not in partial
    assert not (tmp_path / "resumed" / "gaussians.ply").exists()
    assert not leftover_temp_files(tmp_path / "resumed")

    seen = []
    resumed = run_active(
        tiny_dataset, tmp_path / "resumed", cfg, on_round=lambda rec: seen.append(rec["round"]), progress=False
    )
    assert seen == [2]  # rounds 0 and 1 are not recomputed
    assert resumed["selected"] == straight["selected"]
    for a, b in zip(
        load_gaussians(tmp_path / "resumed" / "gaussians.ply").tensors(),
        load_gaussians(straight_dir / "gaussians.ply").tensors(),
        strict=True,
    ):
        assert torch.equal(a, b)
    again = run_active(tiny_dataset, tmp_path / "resumed", cfg, on_round=seen.append, progress=False)
    assert again == resumed and seen == [2]  # a finished run is not recomputed


@pytest.mark.parametrize("mode", ["continue", "reset"])
def test_resume_inside_the_final_training(tiny_dataset, tmp_path, mode):
    """The final training is checkpointed in chunks: an interruption there resumes from the last chunk, and
    chunked or not, interrupted or not, the final Gaussians are bit-identical."""
    cfg = tiny_active_config(mode=mode, total_iterations=24)
    straight = run_active(tiny_dataset, tmp_path / "straight", cfg, progress=False)

    class Interrupt(Exception):
        pass

    seen = []

    def stop_at_second_chunk(iteration):
        seen.append(iteration)
        if len(seen) == 2:
            raise Interrupt

    with pytest.raises(Interrupt):
        run_active(
            tiny_dataset,
            tmp_path / "resumed",
            cfg,
            final_checkpoint_every=4,
            on_final_checkpoint=stop_at_second_chunk,
            progress=False,
        )
    assert not (tmp_path / "resumed" / "gaussians.ply").exists()
    rounds = []
    resumed = run_active(
        tiny_dataset,
        tmp_path / "resumed",
        cfg,
        final_checkpoint_every=4,
        on_final_checkpoint=seen.append,
        on_round=rounds.append,
        progress=False,
    )
    assert rounds == []  # every selection was kept
    assert seen[2] == seen[1] + 4 and seen[-1] == 24  # training went on from the second chunk's checkpoint
    assert resumed["final"]["training"]["resumed_from_iteration"] == seen[1]
    assert resumed["selected"] == straight["selected"]
    for a, b in zip(
        load_gaussians(tmp_path / "resumed" / "gaussians.ply").tensors(),
        load_gaussians(tmp_path / "straight" / "gaussians.ply").tensors(),
        strict=True,
    ):
        assert torch.equal(a, b)
    assert not leftover_temp_files(tmp_path / "resumed")
    with pytest.raises(ValueError, match="final_checkpoint_every"):
        run_active(tiny_dataset, tmp_path / "other", cfg, final_checkpoint_every=0, progress=False)


def test_mismatched_config_is_refused_unless_overwrite(tiny_dataset, tmp_path):
    run = tmp_path / "run"
    short = dict(total_iterations=8, iterations_per_view=1)
    run_active(tiny_dataset, run, tiny_active_config(budget=3, **short), progress=False)
    with pytest.raises(ValueError, match=r"differing keys: active\.budget, active\.seed"):
        run_active(tiny_dataset, run, tiny_active_config(budget=4, seed=1, **short), progress=False)
    out = run_active(tiny_dataset, run, tiny_active_config(budget=4, seed=1, **short), overwrite=True, progress=False)
    assert len(out["selected"]) == 4


def test_fused_method_logs_k_and_physics_scores(tiny_dataset, tmp_path):
    calls = []

    def fake_physics(gaussians):
        """A stand-in for the five probes: D_g = distance of g from the origin."""
        calls.append(gaussians.num)
        return gaussians.means.detach().norm(dim=-1).double()

    cfg = tiny_active_config(method="fisher+fluid", budget=4, mode="reset", total_iterations=12)
    rounds = run_active(tiny_dataset, tmp_path / "run", cfg, physics_fn=fake_physics, progress=False)
    assert len(calls) == 2  # the probes run once per selection
    for rec in rounds["rounds"]:
        k = max(cfg.budget - rec["n_selected"], 2)
        assert rec["k"] == k and len(rec["shortlist"]) == k
        physics = rec["scores"]["physics"]
        scored = {int(i) for i, v in physics.items() if v is not None}
        assert scored == set(rec["shortlist"])
        assert rec["pick"] == max(rec["shortlist"], key=lambda i: physics[str(i)])
        assert rec["physics"]["source"] == "custom"
        assert rec["training"]["iterations"] == rec["n_selected"] * cfg.iterations_per_view
        assert rec["timing"]["probes"] == rec["physics"]["seconds"] > 0  # the probes are their own part
    assert rounds["final"]["iterations"] == cfg.total_iterations  # reset: a fresh full-length final run
    _check_timing(rounds)


def _check_timing(rounds: dict) -> None:
    """Every round's parts add up to its wall time, and the run's split sums the rounds and the final training."""
    for rec in rounds["rounds"]:
        parts = rec["timing"]
        assert set(parts) == set(PARTS) and all(v >= 0 for v in parts.values())
        assert sum(parts.values()) == pytest.approx(rec["round_seconds"], rel=1e-9, abs=1e-9)
        assert parts["training"] >= rec["training"]["seconds"] > 0 and rec["cpu_seconds"] > 0
    run = rounds["final"]["timing"]
    for part in PARTS:
        from_rounds = sum(rec["timing"][part] for rec in rounds["rounds"])
        extra = {"training": rounds["final"]["training"]["seconds"]}.get(part, 0.0)
        if part == "other":
            assert run["seconds"][part] >= from_rounds
        else:
            assert run["seconds"][part] == pytest.approx(from_rounds + extra)
    assert run["total_seconds"] == pytest.approx(sum(run["seconds"].values()))
    assert sum(run["share"].values()) == pytest.approx(1.0)


def test_round_timing_split_by_hand():
    t = round_timing(round_seconds=10.0, training=2.0, selection=7.0, visual=4.0, probes=2.5, parts=0.25)
    assert t == {"training": 2.0, "visual": 4.0, "probes": 2.5, "scoring": 0.75, "other": 0.75}
    run = run_timing([{"timing": t, "cpu_seconds": 6.0}] * 2, final_training=4.0, final_other=0.5)
    assert run["seconds"] == {"training": 8.0, "visual": 8.0, "probes": 5.0, "scoring": 1.5, "other": 2.0}
    assert run["total_seconds"] == 24.5 and run["rounds_cpu_seconds"] == 12.0
    assert run["share"]["visual"] == pytest.approx(8.0 / 24.5)
    line = timing_line(run, visual_name("fisher+fluid"))
    assert line.startswith("time: training 8.0 s (33%), FisherRF 8.0 s (33%), probes 5.0 s (20%), scoring 1.5 s (6%)")
    assert line.endswith("; 24.5 s in all")
    assert visual_name("variance+area") == "variance" and visual_name("random") == "random"


def test_real_probes_inside_the_loop(tiny_dataset, tmp_path):
    """The five-probe physics really runs inside a round: a solid forms, D-bar is finite and positive, and the
    physics planner picks the shortlisted view of largest S(T). The 4-iteration torus is barely opaque: at the
    default tau = 0.3 no lattice point reaches it (measured: 0 solid particles, the empty-solid fallback); at
    tau = 0.05 about 700 do, so the probes meet a solid."""
    physics = PhysicsConfig(
        particle_radius=0.1, steps=8, dt=0.004, directions=("-x",), empty_reference=False, opacity_threshold=0.05
    )
    rounds = run_active(
        tiny_dataset, tmp_path / "run", tiny_active_config(method="physics", budget=3, physics=physics), progress=False
    )
    rec = rounds["rounds"][0]
    phys = rec["physics"]
    assert "error" not in phys, f"the probes did not run: {phys['error']}"
    assert phys["solid_particles"] > 100
    assert math.isfinite(phys["dbar"]) and phys["dbar"] > 0
    assert set(phys["dbar_per_direction"]) == {"-x"}
    assert phys["dbar_per_direction"]["-x"] == pytest.approx(phys["dbar"])  # one probe: its D-bar is the mean
    scores = {int(i): v for i, v in rec["scores"]["physics"].items()}
    assert all(math.isfinite(v) and v > 0 for v in scores.values())
    assert rec["pick"] == max(scores, key=scores.get)


def test_the_rounds_run_the_empty_scene_only_for_a_planner_that_reads_it(tiny_dataset, tmp_path):
    """The empty-scene probes cost as much as the probes; only fisher+excess reads them, so the rounds of every other
    planner leave them out (the recorded config keeps the user's setting)."""
    from nbv.active.loop import ActiveRun
    from nbv.plan import PLANNERS, reads_empty_scene

    assert [m for m in PLANNERS if reads_empty_scene(m)] == ["fisher+excess"]
    for method, runs_empty in (("fisher+fluid", False), ("physics", False), ("fisher+excess", True)):
        cfg = tiny_active_config(method=method)
        assert cfg.physics.empty_reference  # the default
        run = ActiveRun(tiny_dataset, tmp_path / method, cfg, progress=False)
        assert run.physics_config.empty_reference is runs_empty
        assert run.config.physics.empty_reference


# ---- CLI -----------------------------------------------------------------------------------------


def test_active_cli_smoke(tiny_dataset, tmp_path, capsys):
    from apps.cli import main

    run = tmp_path / "run"
    args = [
        "active",
        str(tiny_dataset),
        "-o",
        str(run),
        "--method",
        "random",
        "--preset",
        "cpu-small",
        "--res",
        "24",
        "--budget",
        "3",
        "--iters-per-view",
        "2",
        "--iterations",
        "10",
        "--init-points",
        "150",
        "--max-gaussians",
        "300",
        "--sh-degree",
        "0",
        "--backend",
        "torch",
        "--threads",
        "1",
        "--no-progress",
    ]
    assert main(args) == 0
    rounds = json.loads((run / "rounds.json").read_text())
    assert len(rounds["selected"]) == 3
    # the time split is printed at the end, as rounds.json keeps it
    assert timing_line(rounds["final"]["timing"], "random") in capsys.readouterr().out
    assert (run / "gaussians.ply").is_file()
    # bad input fails before any training and names the option
    assert main(args[:3] + [str(tmp_path / "bad"), "--initial-views", "0,99", "--res", "24"]) == 2
    assert not (tmp_path / "bad" / "checkpoint.pt").exists()
    assert main(args + ["--seed", "3"]) == 2  # another config in the same folder


def test_write_atomic_leaves_nothing_behind_on_failure(tmp_path):
    from nbv.io import write_atomic, write_json_atomic

    target = tmp_path / "data.json"
    write_json_atomic(target, {"a": float("nan"), "b": (1, 2)})
    assert json.loads(target.read_text()) == {"a": None, "b": [1, 2]}  # strict JSON: NaN -> null

    def half_write(tmp):
        tmp.write_text('{"partial": ')
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomic(target, half_write)
    assert json.loads(target.read_text()) == {"a": None, "b": [1, 2]}  # the old file is intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.json"]  # and no temporary file is left


def test_coverage_control_runs_in_the_loop_without_probes(tiny_dataset, tmp_path):
    def no_physics(gaussians):
        raise AssertionError("fisher+area must not run the probes")

    cfg = tiny_active_config(method="fisher+area", budget=4, mode="reset", total_iterations=12)
    rounds = run_active(tiny_dataset, tmp_path / "run", cfg, physics_fn=no_physics, progress=False)
    assert len(rounds["selected"]) == 4
    for rec in rounds["rounds"]:
        assert "physics" not in rec  # no probe ran, so no probe record
        assert rec["k"] == max(cfg.budget - rec["n_selected"], 2) == len(rec["shortlist"])
        coverage = rec["scores"]["physics"]
        assert all(coverage[str(i)] > 0 for i in rec["shortlist"])
        assert rec["pick"] == max(rec["shortlist"], key=lambda i: coverage[str(i)])


class _Payload:
    """A pickle that runs a shell command while it loads (what a hostile checkpoint.pt would hold)."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        import os

        return (os.system, (f"touch {self.marker}",))


def test_planted_checkpoint_is_refused_and_not_executed(tiny_dataset, straight_run, tmp_path):
    """A checkpoint.pt carrying an os.system payload is refused with a message naming the file and the fix, and
    the payload never runs (torch.load with weights_only=True); a real checkpoint still resumes."""
    import shutil

    from nbv.active.run_dir import load_checkpoint

    cfg, straight_dir, _ = straight_run
    run = tmp_path / "run"
    shutil.copytree(straight_dir, run)
    assert load_checkpoint(run / "checkpoint.pt")["phase"] == "done"  # plain types and tensors only
    marker = tmp_path / "pwned"
    torch.save({"version": 1, "evil": _Payload(marker)}, run / "checkpoint.pt")
    with pytest.raises(ValueError, match=r"checkpoint\.pt is refused.*--overwrite"):
        run_active(tiny_dataset, run, cfg, progress=False)
    assert not marker.exists()
    (run / "checkpoint.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match=r"checkpoint\.pt is not a readable checkpoint"):
        run_active(tiny_dataset, run, cfg, progress=False)
    torch.save({"version": 1}, run / "checkpoint.pt")
    with pytest.raises(ValueError, match=r"checkpoint\.pt is not a checkpoint of `fluidgs active`"):
        run_active(tiny_dataset, run, cfg, progress=False)


def test_a_resume_removes_temporary_files_left_by_sigkill(tiny_dataset, straight_run, tmp_path):
    """A run killed at once (SIGKILL) mid-write leaves a .fgs-*.tmp in its folder: the next run there removes it
    (the run owns its folder), and keeps every other file."""
    import shutil

    cfg, straight_dir, straight = straight_run
    run = tmp_path / "run"
    shutil.copytree(straight_dir, run)
    (run / ".fgs-0badc0de.tmp").write_bytes(b"half a checkpoint")
    (run / "notes.tmp").write_text("the user's")
    assert run_active(tiny_dataset, run, cfg, progress=False) == straight
    assert not (run / ".fgs-0badc0de.tmp").exists() and (run / "notes.tmp").exists()
