"""Smoke test of `fluidgs bench probes` on the bundled asset at a coarse radius and few steps."""

import json
import re

import pytest

from apps import cli

from helpers.logs import error_text


def test_bench_probes_profiles_and_judges_cuts(assets_dir, tmp_path, capsys):
    out = tmp_path / "probes.json"
    args = ["bench", "probes", "--gaussians", str(assets_dir / "ahmed_gaussians.ply"), "--particle-radius", "0.08"]
    args += ["--steps", "50", "--every", "25", "--window", "25", "--min-steps", "25", "--fixed", "25"]
    args += ["--cameras", "4", "--tolerances", "0.5", "--json", str(out), "--save", str(tmp_path / "t.npz")]
    assert cli.main([*args, "--rounding", "1"]) == 0
    text = capsys.readouterr().out
    assert "neighbors" in text and "aggregation" in text and "fixed 25" in text and "rule tol 0.5" in text
    assert "rounding floor (1 uncut runs with dt nudged by 1e-06 of itself" in text
    figures = json.loads(out.read_text())
    probes = {p["probe"]: p for p in figures["probes"]}
    assert set(probes) == {"-x", "+x", "-z", "+z", "-y", "empty -x", "empty +x", "empty -z", "empty +z", "empty -y"}
    assert all(p["steps"] == 50 and 0 <= p["reached"] <= 1 and p["fluid"] > 0 for p in probes.values())
    fixed = next(c for c in figures["cuts"] if c["cut"] == "fixed 25")
    assert fixed["stops"] == {d: 25 for d in ("-x", "+x", "-z", "+z", "-y")} and fixed["step_share"] == 0.5
    floor = figures["rounding_floor"]
    assert all(len(floor[k]) == 1 for k in ("views", "dg", "ratio")) and -1 <= floor["dg"][0] <= 1
    assert all(isinstance(c["within_rounding_floor"], bool) for c in figures["cuts"])
    # the same run judged against its own saved answer agrees exactly (the sums are exact integers), so it lies
    # within that run's rounding floor
    assert cli.main([*args[:-4], "--against", str(tmp_path / "t.npz")]) == 0
    text = capsys.readouterr().out
    assert "views Spearman 1.000, D_g Spearman 1.000" in text and "within its rounding floor" in text
    assert text.rstrip().splitlines()[-2].endswith(": yes")


def _fail_if_probes_run(monkeypatch):
    import nbv.bench.probe_profile as profile

    def trace_probes(*args, **kwargs):
        raise AssertionError("the probes ran before the outputs were checked")

    monkeypatch.setattr(profile, "trace_probes", trace_probes)


@pytest.mark.parametrize("option", ["--json", "--save"])
@pytest.mark.parametrize("where", ["proc", "file"])
def test_bench_probes_checks_its_outputs_before_any_work(option, where, tmp_path, monkeypatch, caplog):
    """`--json` and `--save` were first written after the whole profile: an output under a file or in an unwritable
    folder failed only then."""
    _fail_if_probes_run(monkeypatch)
    (tmp_path / "plain").write_text("x")
    folder = "/proc/fluidgs-no-such-folder" if where == "proc" else str(tmp_path / "plain")
    out = f"{folder}/out.json" if option == "--json" else f"{folder}/t.npz"
    assert cli.main(["bench", "probes", option, out]) == 4
    msg = error_text(caplog)
    assert folder in msg and "choose" in msg and not msg.startswith("[Errno"), msg
    assert (tmp_path / "plain").read_text() == "x"


def test_bench_probes_refuses_an_output_that_is_an_input(assets_dir, tmp_path, monkeypatch, caplog):
    """`--save` names the file numpy writes (``.npz`` appended): it may not be the saved run it is judged against."""
    _fail_if_probes_run(monkeypatch)
    saved = tmp_path / "t.npz"
    saved.write_bytes(b"x")
    assert cli.main(["bench", "probes", "--save", str(tmp_path / "t"), "--against", str(saved)]) == 2
    assert "--save" in error_text(caplog) and "--against" in error_text(caplog) and saved.read_bytes() == b"x"
    caplog.clear()
    assert cli.main(["bench", "probes", "--against", str(tmp_path)]) == 2
    assert f"--against {tmp_path} is a folder" in error_text(caplog)


def _fluid_per_probe(text: str) -> dict[str, int]:
    """{probe: fluid particles} of the profile's table."""
    return {m[1]: int(m[2]) for m in re.finditer(r"^([-+][xyz]) +(\d+) ", text, re.MULTILINE)}


def test_bench_probes_margin_trims_the_slabs(assets_dir, capsys):
    """`--margin` built the probe plan without its solid count: a TypeError once the solid was made."""
    args = ["bench", "probes", "--gaussians", str(assets_dir / "ahmed_gaussians.ply"), "--particle-radius", "0.08"]
    args += ["--steps", "25", "--every", "25", "--fixed", "", "--tolerances", "0.5", "--cameras", "2", "--no-empty"]
    assert cli.main([*args, "--margin", "0.05"]) == 0
    trimmed = _fluid_per_probe(capsys.readouterr().out)
    assert cli.main(args) == 0
    full = _fluid_per_probe(capsys.readouterr().out)
    assert set(trimmed) == set(full) == {"-x", "+x", "-z", "+z", "-y"}
    assert all(trimmed[d] < full[d] for d in full), (trimmed, full)
