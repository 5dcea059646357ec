"""Smoke test of `fluidgs bench probes` on the bundled asset at a coarse radius and few steps."""

import json

from apps import cli


def test_bench_probes_profiles_and_judges_cuts(assets_dir, tmp_path, capsys):
    out = tmp_path / "probes.json"
    args = ["bench", "probes", "--gaussians", str(assets_dir / "ahmed_gaussians.ply"), "--particle-radius", "0.08"]
    args += ["--steps", "50", "--every", "25", "--window", "25", "--min-steps", "25", "--fixed", "25"]
    args += ["--cameras", "4", "--tolerances", "0.5", "--json", str(out), "--save", str(tmp_path / "t.npz")]
    assert cli.main(args) == 0
    text = capsys.readouterr().out
    assert "neighbors" in text and "aggregation" in text and "fixed 25" in text and "rule tol 0.5" in text
    figures = json.loads(out.read_text())
    probes = {p["probe"]: p for p in figures["probes"]}
    assert set(probes) == {"-x", "+x", "-z", "+z", "-y", "empty -x", "empty +x", "empty -z", "empty +z", "empty -y"}
    assert all(p["steps"] == 50 and 0 <= p["reached"] <= 1 and p["fluid"] > 0 for p in probes.values())
    fixed = next(c for c in figures["cuts"] if c["cut"] == "fixed 25")
    assert fixed["stops"] == {d: 25 for d in ("-x", "+x", "-z", "+z", "-y")} and fixed["step_share"] == 0.5
    # the same run judged against its own saved answer agrees exactly (the sums are exact integers)
    assert cli.main([*args[:-4], "--against", str(tmp_path / "t.npz")]) == 0
    assert "views Spearman 1.000, D_g Spearman 1.000" in capsys.readouterr().out
