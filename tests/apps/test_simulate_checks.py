"""`fluidgs simulate`: inputs refused in one line naming the option and its limit (dt, viscosity, speed, a non-UTF-8
file name), a diverged result's timings, and outputs that fail on a full disk named in words."""

import shutil

import pytest

from apps import cli

from helpers.logs import error_text
from helpers.sphere_run import FAST, simulate_sphere


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """A 300-Gaussian sphere, four cameras and its -x RESULT.h5 (simulate, 20 coarse steps)."""
    return simulate_sphere(tmp_path_factory.mktemp("more"))


def test_a_tiny_dt_is_called_too_small_not_too_large(data, tmp_path, caplog):
    out = tmp_path / "r.h5"
    assert cli.main(["simulate", str(data["ply"]), "-o", str(out), "--directions=-x", *FAST, "--dt", "1e-300"]) == 2
    msg = error_text(caplog)
    assert "--dt must be at least 1e-08 s" in msg and "too small, not too large" in msg and "reduce dt" not in msg
    assert not out.exists()


def test_a_huge_viscosity_is_refused_naming_the_viscosity_and_its_limit(data, tmp_path, caplog):
    """`--viscosity 1e6` diverged at step 2 ("fluid speed 2.55e+04 m/s exceeds max_speed; reduce dt")."""
    out = tmp_path / "r.h5"
    args = ["simulate", str(data["ply"]), "-o", str(out), "--directions=-x", *FAST, "--viscosity", "1e6"]
    assert cli.main(args) == 2
    msg = error_text(caplog)
    assert "viscosity 1e+06 Pa s is above the stability limit of the explicit viscosity step" in msg
    assert "lower viscosity to 800 Pa s or less" in msg and not out.exists()


def test_speed_0_is_refused_naming_the_option(data, tmp_path, caplog):
    """`--speed 0` completed with D-bar = 0 and no warning."""
    out = tmp_path / "r.h5"
    assert cli.main(["simulate", str(data["ply"]), "-o", str(out), "--directions=-x,-y", *FAST, "--speed", "0"]) == 2
    msg = error_text(caplog)
    assert "--speed is 0 m/s: the probes -x would have no inflow and measure nothing" in msg and not out.exists()
    from nbv.physics import PhysicsConfig

    assert PhysicsConfig(speed=0.0, directions=("-y",)).speed == 0.0  # the -y probe falls from rest: allowed


def test_huge_counts_are_written_in_powers_of_ten():
    from nbv.physics.memory import _count

    assert _count(1234567) == "1,234,567" and _count(1.65e114) == "1.65e+114"


def test_a_diverged_result_records_a_positive_simulation_time(data):
    """A probe that diverged after some aggregated steps recorded simulation = probe time (0: not added) minus
    aggregation time (added each step): -0.22 s."""
    from nbv.physics import PhysicsConfig, ProbeDiverged, simulate_gaussians
    from recon import load_gaussians

    cfg = PhysicsConfig(
        particle_radius=0.08, steps=20, dt=0.004, empty_reference=False, directions=("-x",), solver={"max_speed": 3.05}
    )
    with pytest.raises(ProbeDiverged) as info:
        simulate_gaussians(load_gaussians(data["ply"]), cfg, progress=False)
    t = info.value.result.timings
    assert info.value.step > 0 and t["aggregation"] > 0 and t["simulation"] > 0


def test_a_non_utf8_file_name_is_refused_before_the_run(data, tmp_path, caplog):
    """A non-UTF-8 Gaussian file name ran the whole job, then failed writing RESULT.h5 ("'utf-8' codec can't
    encode character '\\udcff'") without naming the file."""
    import os
    import time

    odd = os.fsdecode(os.fsencode(str(tmp_path)) + b"/m\xff.ply")
    shutil.copy(data["ply"], odd)
    t0 = time.monotonic()
    assert cli.main(["simulate", odd, "-o", str(tmp_path / "r.h5"), "--directions=-x", *FAST]) == 2
    assert cli.main(["simulate", str(data["ply"]), "-o", odd[:-4] + ".h5", "--directions=-x", *FAST]) == 2
    assert time.monotonic() - t0 < 5
    msg = error_text(caplog)
    assert "GAUSSIANS b'" in msg and "--output b'" in msg and "m\\xff" in msg and "is not valid UTF-8" in msg
    assert not (tmp_path / "r.h5").exists()


H5_FULL = (
    "Unable to synchronously create dataset (file write failed: time = Thu Dec  3 05:00:00 2026, filename = "
    "'/tmp/x/.fgs-0a1b2c3d.tmp', file descriptor = 5, errno = 28, error message = 'No space left on device', buf = "
    "0x55d0, total write size = 4096, bytes this sub-write = 4096, bytes actually written = 18446744073709551615)"
)


def test_a_full_disk_in_h5py_is_named_in_words(data, tmp_path, monkeypatch, caplog):
    """A full disk printed h5py's raw text (time, file descriptor, buffer address...)."""
    import nbv.io

    def full(*args, **kwargs):
        raise OSError(H5_FULL)

    monkeypatch.setattr(nbv.io.h5py.File, "create_dataset", full)
    out = tmp_path / "r.h5"
    assert cli.main(["simulate", str(data["ply"]), "-o", str(out), "--directions=-x", *FAST]) == 4
    msg = error_text(caplog)
    assert f"cannot write {out}: No space left on device (errno 28)" in msg and "file descriptor" not in msg
    assert "no output was written" in msg and sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_second_output_that_fails_says_which_survived(data, tmp_path, monkeypatch, caplog):
    """RESULT.h5 written, then the coloured .ply hits a full disk: the message says RESULT.h5 is complete."""
    import nbv.outputs
    from fluidsim.files import output_errors

    def full(gaussians, values, path, columns, *reached):
        with output_errors(path):
            raise OSError(H5_FULL)

    monkeypatch.setattr(nbv.outputs, "save_colored_gaussians", full)
    out, ply = tmp_path / "r.h5", tmp_path / "c.ply"
    assert cli.main(["simulate", str(data["ply"]), "-o", str(out), "--ply", str(ply), "--directions=-x", *FAST]) == 4
    msg = error_text(caplog)
    assert f"cannot write {ply}: No space left on device" in msg and f"written before it, complete: {out}" in msg
    assert out.exists() and not ply.exists()
