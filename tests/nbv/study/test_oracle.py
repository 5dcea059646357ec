"""The oracle study (:mod:`nbv.study.oracle`), its calibration (:mod:`nbv.study.calibration`) and the farthest-view
planner (:mod:`nbv.plan.fvs`)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from nbv.plan import PLANNERS, PlanningContext, make_planner
from nbv.plan.fvs import farthest_view_distances, farthest_view_order
from nbv.ranking import spearman
from nbv.study import calibration as cal
from nbv.study.oracle import check_scenes, run_oracle
from nbv.study.oracle_config import RULES, OracleConfig
from nbv.study.oracle_summary import bootstrap_interval, regret, summarise
from recon.camera import Camera
from recon.gaussians import GaussianSet

from helpers.paths import TORUS
from helpers.training import TINY_TRAIN


def ring(count: int, radius: float = 3.0) -> list[Camera]:
    angles = np.arange(count) * 2 * math.pi / count
    eyes = [(radius * math.cos(a), 0.0, radius * math.sin(a)) for a in angles]
    return [Camera.look_at(e, (0, 0, 0), (0, 1, 0), 16, 16, math.radians(50), name=f"c{k}") for k, e in enumerate(eyes)]


# ---- farthest view sampling ----------------------------------------------------------------------------
def test_fvs_distances_and_greedy_order_on_a_ring():
    cams = ring(8)
    # selected: camera 0; the farthest is the opposite one (4), then the two at 90 degrees (2 and 6)
    d = farthest_view_distances(cams[1:], [cams[0]])
    chord = [2 * 3.0 * math.sin(math.pi * k / 8) for k in range(1, 8)]
    assert np.allclose(d, chord)
    order = farthest_view_order(cams[1:], [cams[0]], 3)
    assert [cams[1:][i].name for i in order] == ["c4", "c2", "c6"]
    assert farthest_view_distances(cams, []) == [math.inf] * 8


def test_a_thin_rule_brings_the_coverage_of_its_mask_as_a_control(tmp_path):
    cfg = OracleConfig(**{**tiny(tmp_path, tmp_path, rules=["thin"]), "probes": {"a": {}, "b": {}}})
    assert cfg.physics_rules() == ["thin:a", "thin:b", "thin-area:a", "thin-area:b"]
    assert {"coverage", "thin-area:a"} <= set(cfg.scored_rules())
    assert RULES["thin-occ"].own_control == "thin-area-occ" and RULES["fluid"].own_control is None


def test_fvs_planner_is_registered_and_picks_the_farthest():
    assert "fvs" in PLANNERS and "fvs" in RULES
    g = GaussianSet.from_points(torch.zeros(4, 3), scale=0.1)
    cams = ring(6)
    from recon.datasets import View

    ctx = PlanningContext(
        gaussians=g,
        train_views=[View(cams[0], None, None, "c0")],
        candidates=cams[1:],
        candidate_ids=list(range(1, 6)),
        n_selected=1,
        budget=4,
        background=torch.ones(3),
    )
    sel = make_planner("fvs", seed=2).select(ctx)
    assert cams[1:][sel.pick].name == "c3" and sel.shortlist[0] == sel.pick and len(sel.shortlist) == 5


# ---- calibration kernels ---------------------------------------------------------------------------------
def box_mesh(half: float = 0.5):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_box(2 * half, 2 * half, 2 * half)
    m.translate((-half, -half, -half))
    return np.asarray(m.vertices), np.asarray(m.triangles)


def test_surface_distance_matches_brute_force_and_the_box_formula():
    import open3d as o3d

    rng = np.random.default_rng(0)
    sphere = o3d.geometry.TriangleMesh.create_sphere(0.7, resolution=8)
    v, t = np.asarray(sphere.vertices), np.asarray(sphere.triangles)
    p = rng.uniform(-1.2, 1.2, (200, 3))
    fast, slow = cal.surface_distance(p, v, t), cal.surface_distance_reference(p, v, t)
    assert np.allclose(fast, slow, atol=2e-6)  # open3d works in float32
    bv, bt = box_mesh()
    q = rng.uniform(-1.0, 1.0, (300, 3))
    outside = np.linalg.norm(np.maximum(np.abs(q) - 0.5, 0.0), axis=1)
    inside = np.minimum(0.5 - np.abs(q), 1.0).min(axis=1)
    exact = np.where((np.abs(q) <= 0.5).all(axis=1), inside, outside)
    assert np.allclose(cal.surface_distance_reference(q, bv, bt), exact, atol=1e-12)
    assert np.allclose(cal.surface_distance(q, bv, bt), exact, atol=2e-6)


def test_surface_samples_lie_on_the_surface_uniformly():
    bv, bt = box_mesh()
    s = cal.sample_surface(bv, bt, 6000, seed=1)
    assert np.allclose(np.abs(s).max(axis=1), 0.5)
    per_face = [(np.isclose(s[:, a], sign * 0.5)).sum() for a in range(3) for sign in (-1, 1)]
    assert min(per_face) > 850 and max(per_face) < 1150  # 1000 per face expected (6 equal faces)


def test_ause_is_zero_for_a_perfect_ranking_and_largest_for_the_inverted_one():
    rng = np.random.default_rng(3)
    e = rng.random(500)
    assert cal.ause(e, e) == pytest.approx(0.0, abs=1e-12)
    assert cal.ause(2 * e + 1, e) == pytest.approx(0.0, abs=1e-12)  # only the order counts
    inverted, noise = cal.ause(-e, e), cal.ause(rng.random(500), e)
    assert inverted > noise > 0
    assert cal.ause(np.zeros(500), e) == pytest.approx(inverted, rel=1e-12)  # ties: the worst order
    curve = cal.sparsification_curve(e, e, 10)
    assert curve[0] == pytest.approx(e.mean()) and (np.diff(curve) <= 1e-12).all()


def test_missing_samples_use_the_2_sigma_ellipsoid():
    g = GaussianSet(
        torch.zeros(1, 3, dtype=torch.float64),
        torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64),
        torch.log(torch.tensor([[0.1, 0.2, 0.05]], dtype=torch.float64)),
        torch.tensor([2.0], dtype=torch.float64),
        torch.zeros(1, 1, 3, dtype=torch.float64),
    )
    pts = np.array([[0.19, 0, 0], [0.21, 0, 0], [0, 0.39, 0], [0, 0.41, 0], [0, 0, 0.09], [0, 0, 0.11]])
    assert cal.missing_samples(pts, g).tolist() == [False, True, False, True, False, True]
    assert cal.missing_samples(pts, g, min_opacity=0.95).all()  # sigmoid(2) = 0.88 covers nothing above 0.95


def test_visible_samples_hide_the_far_side_of_a_box():
    bv, bt = box_mesh()
    cam = Camera.look_at((3.0, 0.0, 0.0), (0, 0, 0), (0, 1, 0), 32, 32, math.radians(50))
    pts = np.array([[0.5, 0.1, 0.1], [-0.5, 0.1, 0.1], [0.1, 0.5, 0.1], [0.5, 5.0, 0.0]])
    # front face seen; back face hidden; the top face is edge-on from this camera (hidden behind the front edge);
    # a point outside the image is not seen
    vis = cal.visible_samples(pts, [cam], bv, bt)[0].tolist()
    assert vis[0] and not vis[1] and not vis[3]


# ---- statistics --------------------------------------------------------------------------------------
def test_bootstrap_interval_resamples_whole_groups():
    mean, lo, hi = bootstrap_interval([[1.0, 1.0], [3.0]], 500)
    assert mean == pytest.approx(5 / 3) and 1.0 <= lo <= mean <= hi <= 3.0
    assert bootstrap_interval([[2.0, 2.0], [2.0]], 500) == (2.0, 2.0, 2.0)
    m, lo, hi = bootstrap_interval([[1.0, 2.0]], 500)
    assert m == 1.5 and math.isnan(lo) and math.isnan(hi)  # one (scene, seed) pair: no interval
    assert math.isnan(bootstrap_interval([[math.nan]], 500)[0])


def test_regret_inside_the_shortlist():
    gains = [0.1, 0.5, 0.3, 0.9]
    assert regret([0, 5, 2, 9], gains, [0, 1, 2]) == pytest.approx(0.0)  # the outside 0.9 does not count
    assert regret([3, 1, 2, 0], gains, [0, 1, 2]) == pytest.approx(0.5 - 0.1)


# ---- config and bad input ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    """The torus at 24 px: 6 candidate views, 3 test views (and its mesh)."""
    from recon.mesh_render import MeshDatasetConfig, render_mesh_dataset

    out = tmp_path_factory.mktemp("oracle") / "torus"
    render_mesh_dataset(
        TORUS, out, MeshDatasetConfig(n_train=6, n_test=3, resolution=24, supersample=1), progress=False
    )
    return out


def tiny(tmp_path, dataset, **over) -> dict:
    base = {
        "scenes": [str(dataset)],
        "seeds": [0],
        "states": [2],
        "horizon": 3,
        "output": str(tmp_path / "out"),
        "rules": [
            "fisher",
            "fvs",
            "random",
            "coverage",
            "coverage-occ",
            "fluid-occ",
            "thin-occ",
            "thin-area-occ",
            "ratio-occ",
            "transparent-occ",
        ],
        "active": {
            "resolution": 16,
            "iterations_per_view": 3,
            "total_iterations": 60,
            "budget": 4,
            "train": TINY_TRAIN,
            "backend": "torch",
        },
        "probes": {"coarse": {"particle_radius": 0.08, "steps": 20, "dt": 0.004, "directions": ["-x"]}},
        "bootstrap": 200,
    }
    return {**base, **over}


def test_old_rule_names_still_load_with_a_note(tmp_path, caplog):
    """Configs written with the values' old names (divergence, ones, thinmask) read as the rules they name."""
    path = tmp_path / "old.json"
    path.write_text(json.dumps(tiny(tmp_path, "x", rules=["fisher", "divergence-occ", "ones", "thinmask-occ"])))
    with caplog.at_level("WARNING", logger="nbv.study.oracle_config"):
        cfg = OracleConfig.load(path)
    assert cfg.rules == ("fisher", "fluid-occ", "coverage", "thin-area-occ")
    assert "old names" in caplog.text and "thinmask-occ" in caplog.text


@pytest.mark.parametrize(
    ("over", "key"),
    [
        ({"rules": ["fisher", "fluid-occc"]}, "rules"),
        ({"horizon": 0}, "horizon"),
        ({"states": [1]}, "states"),
        ({"states": [1e308]}, "states"),  # was named 'active.budget', built from the states
        ({"planner": "fisherrf"}, "planner"),
        ({"probes": {"a": {"steps": -1}}}, "probes"),
        ({"seeds": list(range(1_000_000))}, "seeds"),  # about 46 days of work: refused before any
        ({"seeds": [2**62]}, "seeds"),
        ({"horizon": 10**14}, "horizon"),  # ran for ever: no upper bound
        ({"bootstrap": 10**12}, "bootstrap"),
        ({"active": {"total_iterations": 10**14}}, "active.total_iterations"),  # ran; then spoke of TrainConfig
        ({"active": {"resolution": 10**8}}, "active.resolution"),  # spoke of "Camera 'r_000'" after loading
        ({"active": {"iterations_per_view": 10**4}}, "active.total_iterations"),  # spoke of ActiveConfig
    ],
)
def test_bad_config_names_the_key(tmp_path, over, key):
    with pytest.raises(ValueError, match=f"'{key}'"):
        OracleConfig(**tiny(tmp_path, "x", **over))


def test_states_beyond_the_pool_and_scenes_without_test_views_are_refused(tmp_path, tiny_dataset):
    with pytest.raises(ValueError, match="'states'.*leaves no candidate"):
        check_scenes(OracleConfig(**tiny(tmp_path, tiny_dataset, states=[6])))
    no_test = tmp_path / "notest"
    no_test.mkdir()
    for name in ("transforms_train.json", "dataset.json", "mesh.ply"):
        (no_test / name).write_bytes((tiny_dataset / name).read_bytes())
    (no_test / "train").symlink_to(tiny_dataset / "train")
    meta = json.loads((tiny_dataset / "transforms_test.json").read_text())
    (no_test / "transforms_test.json").write_text(json.dumps({**meta, "frames": []}))
    with pytest.raises(ValueError, match="'scenes'.*no test views"):
        check_scenes(OracleConfig(**tiny(tmp_path, no_test)))


def test_cli_exits_2_before_any_training(tmp_path, tiny_dataset):
    from apps.cli import main

    cfg = tmp_path / "oracle.json"
    cfg.write_text(json.dumps(tiny(tmp_path, tiny_dataset, horizon=0)))
    assert main(["study", "oracle", str(cfg), "--no-progress"]) == 2
    cfg.write_text(json.dumps(tiny(tmp_path, tiny_dataset, states=[6])))
    assert main(["study", "oracle", str(cfg), "--no-progress"]) == 2
    assert not (tmp_path / "out" / "states").exists()
    foreign = tmp_path / "etc"  # "output": "/etc": a folder of other files is never written into
    foreign.mkdir()
    (foreign / "passwd").write_text("root:x:0:0")
    cfg.write_text(json.dumps({**tiny(tmp_path, tiny_dataset), "output": str(foreign)}))
    assert main(["study", "oracle", str(cfg), "--no-progress"]) == 2
    assert sorted(p.name for p in foreign.iterdir()) == ["passwd"]


# ---- the study end to end -------------------------------------------------------------------------------
class InProcess:
    """A serial executor in this process (the test session's Taichi runtime)."""

    def __init__(self) -> None:
        self.calls = 0

    def map(self, fn, jobs):
        for job in jobs:
            self.calls += 1
            yield job, fn(job)


@pytest.fixture(scope="module")
def study(tmp_path_factory, tiny_dataset):
    tmp = tmp_path_factory.mktemp("oracle-run")
    config = OracleConfig(**tiny(tmp, tiny_dataset, seeds=[0, 1], states=[2, 3]))
    ex = InProcess()
    out = run_oracle(config, ex, progress=False)
    return config, out, ex


def test_every_state_is_written_and_the_rules_score_every_candidate(study):
    config, out, ex = study
    assert ex.calls == 4
    states = sorted((Path(config.output) / "states").rglob("state*.json"))
    assert len(states) == 4
    for path in states:
        st = json.loads(path.read_text())
        c = len(st["candidates"])
        assert c == 6 - st["n_selected"] and len(st["selected"]) == st["n_selected"]
        assert set(st["selected"]).isdisjoint(st["candidates"])
        assert set(st["scores"]) == set(config.scored_rules())
        assert all(len(v) == c for v in st["scores"].values())
        o = st["oracle"]
        assert np.allclose(o["gain_psnr"], np.array(o["psnr"]) - o["psnr_base"])
        assert "calibration" in st and len(st["calibration"]["missing"]["per_view"]) == c
        share = st["thin_share"]["coarse"]
        assert 0.0 <= share <= 1.0
        thin, full = np.array(st["scores"]["thin-occ:coarse"]), np.array(st["scores"]["fluid-occ:coarse"])
        assert (thin <= full * (1 + 1e-12)).all()  # D_g masked to the thin or open part: never more
        clear = np.array(st["scores"]["transparent-occ"])  # 1 - opacity in (0, 1): below the coverage
        assert (clear <= np.array(st["scores"]["coverage-occ"])).all() and (clear >= 0).all()
        area = np.array(st["scores"]["thin-area-occ:coarse"])
        cover = np.array(st["scores"]["coverage-occ"])
        assert (area <= cover * (1 + 1e-12)).all()  # the thin part's coverage: never more than the coverage
        if share == 1.0:  # every Gaussian thin or open: the thin rules are the plain ones
            np.testing.assert_array_equal(thin, full)
            np.testing.assert_allclose(area, cover, rtol=1e-12)
    # a larger state of the same (scene, seed) continues the smaller one's selection
    by = {
        (json.loads(p.read_text())["seed"], json.loads(p.read_text())["n_selected"]): json.loads(p.read_text())
        for p in states
    }
    for seed in (0, 1):
        assert by[(seed, 3)]["selected"][:2] == by[(seed, 2)]["selected"]


def test_summary_spearman_agrees_with_an_independent_computation(study):
    from scipy.stats import spearmanr

    config, out, _ = study
    states = [json.loads(p.read_text()) for p in sorted(Path(config.output).rglob("state*.json"))]
    for label in ("fisher", "coverage-occ", "fluid-occ:coarse"):
        rhos = [spearmanr(st["scores"][label], st["oracle"]["gain_psnr"])[0] for st in states]
        rhos = [r for r in rhos if np.isfinite(r)]
        assert out["summary"]["rules"][label]["spearman"][0] == pytest.approx(np.mean(rhos), abs=1e-9)
    again = summarise(config, states)
    assert again["rules"]["fisher"]["spearman"] == pytest.approx(
        out["summary"]["rules"]["fisher"]["spearman"], nan_ok=True
    )
    assert "fluid-occ:coarse" in out["summary"]["paired"] and "| fisher |" in out["markdown"]
    # per seed: the mean over that seed's states, and a table of it (two seeds here)
    for seed in (0, 1):
        rhos = [spearmanr(st["scores"]["fisher"], st["oracle"]["gain_psnr"])[0] for st in states if st["seed"] == seed]
        rhos = [r for r in rhos if np.isfinite(r)]
        got = out["summary"]["rules"]["fisher"]["per_seed"][str(seed)][0]
        assert (got == pytest.approx(np.mean(rhos), abs=1e-9)) if rhos else math.isnan(got)
    assert (
        "By seed (intervals over that seed's scenes):" in out["markdown"] and "| seed 0 | seed 1 |" in out["markdown"]
    )
    # the thin rule also against the coverage of its own mask
    own = out["summary"]["paired"]["thin-occ:coarse vs thin-area-occ:coarse"]
    diffs = [
        spearmanr(st["scores"]["thin-occ:coarse"], st["oracle"]["gain_psnr"])[0]
        - spearmanr(st["scores"]["thin-area-occ:coarse"], st["oracle"]["gain_psnr"])[0]
        for st in states
    ]
    diffs = [d for d in diffs if np.isfinite(d)]
    if diffs:
        assert own["difference"][0] == pytest.approx(np.mean(diffs), abs=1e-9)
    assert own["control"] == "thin-area-occ:coarse" and own["rule"] == "thin-occ:coarse"


@pytest.fixture(scope="module")
def thin_alone(study, tmp_path_factory):
    """A second study of the same scene: seed 0, state 2, only the rules that read the thin mask (no probes)."""
    import nbv.study.oracle as oracle

    def no_probes(*args, **kwargs):
        raise AssertionError("the thin-area rules need the solid only")

    config, _, _ = study
    out = tmp_path_factory.mktemp("oracle-alone") / "alone"
    alone = OracleConfig(
        **{
            **config.to_dict(),
            "output": str(out),
            "seeds": [0],
            "states": [2],
            "rules": ["fisher", "coverage-occ", "thin-area-occ"],
        }
    )
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(oracle, "probe_run", no_probes)
        run_oracle(alone, InProcess(), progress=False)
    return alone


def _state(output, seed: int, n: int) -> dict:
    (path,) = [
        p
        for p in (Path(output) / "states").rglob("state*.json")
        if (json.loads(p.read_text())["seed"], json.loads(p.read_text())["n_selected"]) == (seed, n)
    ]
    return json.loads(path.read_text())


def test_the_thin_mask_rules_alone_run_the_solid_without_the_probes(study, thin_alone):
    config, _, _ = study
    st, full = _state(thin_alone.output, 0, 2), _state(config.output, 0, 2)
    assert st["selected"] == full["selected"]
    # the same mask as the probe run's: the same scores, and no D_g to calibrate
    np.testing.assert_array_equal(st["scores"]["thin-area-occ:coarse"], full["scores"]["thin-area-occ:coarse"])
    assert st["thin_share"] == full["thin_share"]
    assert "fisher diagonal" in st["calibration"]["signals"]
    assert not any(k.startswith(("D_g", "thin")) for k in st["calibration"]["signals"])


def test_pooled_studies_summarise_the_rules_every_state_scored(study, thin_alone, tmp_path):
    from nbv.study.oracle_pool import pool_studies

    config, _, _ = study
    pool = pool_studies([thin_alone.output, config.output])
    # the alone study's state is kept, the full study's copy of it counted as a duplicate
    assert len(pool.states) == 4 and len(pool.duplicates) == 1 and "seed 0 state 2" in pool.duplicates[0]
    assert [s["states"] for s in pool.sources] == [1, 3]
    assert set(pool.config.scored_rules()) == {"fisher", "coverage-occ", "thin-area-occ:coarse"}
    assert "fluid-occ:coarse" in pool.dropped_rules and "fvs" in pool.dropped_rules
    summary = summarise(pool.config, pool.states)
    assert summary["states"] == 4 and set(summary["rules"]) == set(pool.config.scored_rules())
    # the pooled Spearman of a rule is the mean over the pooled states
    from scipy.stats import spearmanr

    rhos = [spearmanr(st["scores"]["fisher"], st["oracle"]["gain_psnr"])[0] for st in pool.states]
    rhos = [r for r in rhos if np.isfinite(r)]
    assert summary["rules"]["fisher"]["spearman"][0] == pytest.approx(np.mean(rhos), abs=1e-9)
    # a study reached with another horizon is refused, naming the key
    other = tmp_path / "other"
    other.mkdir()
    meta = json.loads((Path(config.output) / "oracle-config.json").read_text())
    meta["config"]["horizon"] = 7
    (other / "oracle-config.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="'horizon'"):
        pool_studies([config.output, other])
    with pytest.raises(ValueError, match="not an oracle study folder"):
        pool_studies([config.output, tmp_path])
    # a study that scored only a rule the other did not: nothing in common
    import shutil

    lone = tmp_path / "lone"
    shutil.copytree(thin_alone.output, lone)
    meta = json.loads((lone / "oracle-config.json").read_text())
    meta["config"]["rules"] = ["variance"]
    (lone / "oracle-config.json").write_text(json.dumps(meta))
    for path in (lone / "states").rglob("state*.json"):
        st = json.loads(path.read_text())
        st["config"]["rules"], st["scores"] = ["variance"], {"variance": st["scores"]["fisher"]}
        path.write_text(json.dumps(st))
    with pytest.raises(ValueError, match="share no rule"):
        pool_studies([lone, config.output])  # the states other than the one both hold


def test_oracle_pool_cli_writes_the_pooled_summary_and_refuses_an_input_as_output(study, thin_alone, tmp_path, caplog):
    from apps.cli import main

    config, _, _ = study
    out = tmp_path / "pooled"
    assert main(["study", "oracle-pool", str(config.output), thin_alone.output, "--output", str(out)]) == 0
    text = (out / "oracle.md").read_text()
    assert text.startswith("Pooled from ") and "| fisher |" in text and "States found twice" in text
    assert json.loads((out / "oracle.json").read_text())["pool"]["duplicates"]
    assert main(["study", "oracle-pool", str(config.output), "--output", str(config.output)]) == 2
    assert "is one of the pooled folders" in caplog.text


def test_oracle_pool_names_a_fifo_state_file_instead_of_hanging(study, tmp_path, caplog):
    import os
    import shutil

    from apps.cli import main

    config, _, _ = study
    copy = tmp_path / "copy"
    shutil.copytree(config.output, copy)
    state = next((copy / "states").rglob("state*.json"))
    state.unlink()
    os.mkfifo(state)
    assert main(["study", "oracle-pool", str(copy), "--output", str(tmp_path / "pooled")]) == 2
    assert "is a FIFO" in caplog.text and str(state) in caplog.text


@pytest.mark.parametrize(
    "damage, words",
    [
        ({"oracle": "x"}, "has no 'oracle' object"),
        ({"seed": "zero"}, "has no 'seed' integer"),
        ({"candidates": list(range(1000))}, "that is not 1000 numbers, one per candidate"),
    ],
)
def test_a_damaged_state_is_named_by_the_pool_and_measured_again_by_the_study(study, tmp_path, caplog, damage, words):
    """A state file whose config matched but whose body did not (a string for 'oracle', a seed that is a string, the
    scores of another candidate count) ended both commands in a TypeError traceback or a one-line error that named no
    file."""
    import shutil

    import nbv.study.oracle as oracle
    from apps.cli import main

    config, _, _ = study
    copy = tmp_path / "copy"
    shutil.copytree(config.output, copy)
    state = next((copy / "states").rglob("state*.json"))
    state.write_text(json.dumps({**json.loads(state.read_text()), **damage}))
    assert main(["study", "oracle-pool", str(copy), "--output", str(tmp_path / "pooled")]) == 2
    assert f"the state file {state} " in caplog.text and words in caplog.text
    job = next(j for j in oracle.plan_jobs(replace(config, output=str(copy))) if j["path"] == str(state))
    assert oracle._stored(state, job["config"]) is None


def test_a_finished_study_resumes_without_training(study):
    config, out, _ = study
    ex = InProcess()
    again = run_oracle(config, ex, progress=False)
    assert ex.calls == 0 and again["markdown"] == out["markdown"]


def test_a_thin_area_planner_reaches_a_state_with_the_loops_context(tmp_path, tiny_dataset):
    """The oracle reaches its states through the loop (ActiveRun.reach), whose contexts carry the solid's mask: a
    +thin-area planner makes the picks, the same pick as on the loop's own context."""
    from nbv.active import ActiveRun, planner_seed
    from nbv.study.oracle import plan_jobs, run_state

    over = {"planner": "fisher+thin-area", "states": [3], "rules": ["fisher", "coverage"], "calibration": False}
    config = OracleConfig(**tiny(tmp_path, tiny_dataset, **over))
    (job,) = plan_jobs(config)
    st = run_state(job)
    acfg = config.active_config(0)
    reached = ActiveRun(tiny_dataset, None, acfg, progress=False).reach(2)
    sel = make_planner(acfg.method, **{**dict(acfg.planner), "seed": planner_seed(0, reached.round)}).select(
        reached.context
    )
    assert "solid_mask" in reached.record  # the loop's context ran the mask for the pick
    assert st["selected"] == reached.selected + [reached.context.candidate_ids[sel.pick]]


def test_the_oracle_copies_share_the_schedule(tiny_dataset):
    """Two oracle runs of one state give identical gains (same trainer state, seed and schedule)."""
    from nbv.study.oracle import oracle_gains
    from recon.datasets import load_dataset
    from recon.train import Trainer, initial_gaussians, scene_extent
    from recon.train_config import TrainConfig

    ds = load_dataset(tiny_dataset, resolution=16)
    cams = [v.camera for v in ds.train]
    cfg = TrainConfig.for_iterations(40, **TINY_TRAIN)
    init = initial_gaussians(cfg, cams)

    def new_trainer():
        return Trainer(init, cfg, extent=scene_extent(cams), data_background=ds.background, backend="torch")

    t = new_trainer()
    t.train(ds.train[:2], 6)
    state = t.state_dict()
    a = oracle_gains(new_trainer, state, ds.train[:2], ds.train[2:4], ds.test, ds.background, 3)
    b = oracle_gains(new_trainer, state, ds.train[:2], ds.train[2:4], ds.test, ds.background, 3)
    assert a == b
    assert spearman(a["gain_psnr"], a["gain_psnr"]) == pytest.approx(1.0)


def test_the_functional_target_gives_each_candidate_a_gain_and_its_summary(tmp_path, tiny_dataset):
    """With 'functional', each copy is also measured against the torus mesh (nbv.functional): a functional gain per
    candidate (the copy without it minus with it), the base copy's error beside its floor, and the rules' Spearman
    with the gain in the summary; a study without it keeps its states' key."""
    functional = {"particle_radius": 0.08, "steps": 40, "dt": 0.004, "directions": ["-x"]}
    config = OracleConfig(
        **tiny(tmp_path, tiny_dataset, rules=["fisher", "coverage", "fluid-occ"], functional=functional)
    )
    out = run_oracle(config, InProcess(), progress=False)
    st = json.loads(next((Path(config.output) / "states").rglob("state*.json")).read_text())
    o = st["oracle"]
    assert len(o["gain_functional"]) == len(st["candidates"]) == len(o["gain_psnr"])
    assert np.isfinite(o["functional_error_base"]) and o["functional_error_base"] >= 0
    assert np.isfinite(o["functional_floor_base"])
    errors = np.asarray(o["functional_error"], float)
    np.testing.assert_allclose(o["gain_functional"], o["functional_error_base"] - errors)
    f = out["functional"] if "functional" in out else out["summary"]["functional"]
    assert set(f["rules"]) >= {"fisher", "coverage"} and "fluid-occ:coarse" in f["paired"]
    assert "Functional target" in (Path(config.output) / "oracle.md").read_text()
    plain = OracleConfig(**tiny(tmp_path, tiny_dataset))
    assert "functional" not in plain.to_dict()  # the states of studies without it keep their key
