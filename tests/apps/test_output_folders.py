"""An output that cannot be made (under /proc, or an existing regular file where a folder or a folder's parent is
expected) ends `active`, `demo`, `make-assets` and `ahmed` with exit 4 and one line naming the output and the fix,
before any work: they ended with exit 2 and a bare errno text ("[Errno 17] File exists: ...")."""

import pytest

from apps import cli

from helpers.logs import error_text


def _argv(command: str, out: str, tmp_path) -> list[str]:
    if command == "active":
        (tmp_path / "ds").mkdir(exist_ok=True)
        return ["active", str(tmp_path / "ds"), "-o", out, "--threads", "1"]
    if command == "ahmed":
        return ["ahmed", "-o", f"{out}/body.obj"]
    return [command, "-o", out, "--threads", "1"]


@pytest.mark.parametrize("command", ["active", "demo", "make-assets", "ahmed"])
@pytest.mark.parametrize("where", ["proc", "file"])
def test_an_output_that_cannot_be_made_is_exit_4_naming_it(command, where, tmp_path, caplog, capsys):
    (tmp_path / "plain").write_text("x")
    out = "/proc/fluidgs-no-such-folder" if where == "proc" else str(tmp_path / "plain")
    assert cli.main(_argv(command, out, tmp_path)) == 4
    msg = error_text(caplog)
    assert out in msg and ("choose" in msg or "give" in msg) and not msg.startswith("[Errno"), msg
    assert "Traceback" not in capsys.readouterr().err
    assert (tmp_path / "plain").read_text() == "x"


@pytest.mark.parametrize("option", ["--keep", "--json"])
def test_bench_forces_refuses_an_output_under_a_file_before_any_engine_runs(option, tmp_path, caplog):
    """`bench forces --keep FILE` ran this engine's probe, then failed in the peer's writer with exit 2 and
    "[Errno 20] Not a directory"; `--json` under a file failed after both engines had run."""
    (tmp_path / "plain").write_text("x")
    out = tmp_path / "plain" if option == "--keep" else tmp_path / "plain" / "f.json"
    assert cli.main(["bench", "forces", "--case", "sphere", option, str(out)]) == 4
    assert str(tmp_path / "plain") in error_text(caplog) and "Errno" not in error_text(caplog)
    assert (tmp_path / "plain").read_text() == "x"


def test_bench_render_refuses_a_json_under_a_file_before_timing(tmp_path, monkeypatch, caplog):
    """`bench render --json FILE/x.json` timed every case, then ended with exit 2 and "[Errno 20] Not a
    directory: '.../.fgs-....tmp'"."""
    import recon.render_bench

    def timed(*args, **kwargs):
        raise AssertionError("timed a case before checking --json")

    monkeypatch.setattr(recon.render_bench, "time_case", timed)
    (tmp_path / "plain").write_text("x")
    assert cli.main(["bench", "render", "--repeats", "1", "--json", str(tmp_path / "plain" / "f.json")]) == 4
    assert str(tmp_path / "plain") in error_text(caplog) and "Errno" not in error_text(caplog)


def test_bench_forces_json_is_never_its_solid(tmp_path, caplog):
    solid = tmp_path / "solid.json"
    solid.write_text("x")
    assert cli.main(["bench", "forces", "--solid", str(solid), "--json", str(solid)]) == 2
    assert "would destroy the input" in error_text(caplog) and solid.read_text() == "x"


def test_demo_writes_only_into_its_own_folder(tmp_path, caplog):
    """`demo -o FOLDER` replaced a user's result.h5 in a folder of their files; an earlier demo's folder (its own
    files and views/) is still written again."""
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "result.h5").write_text("y")
    assert cli.main(["demo", "-o", str(tmp_path), "--threads", "1"]) == 2
    assert "notes.txt" in error_text(caplog) and (tmp_path / "result.h5").read_text() == "y"
    from apps.options.demo import output_folder

    earlier = tmp_path / "earlier"
    (earlier / "views").mkdir(parents=True)
    (earlier / "result.h5").write_text("old")
    assert output_folder(earlier) == earlier
