"""fluidsim.files, the one module that writes files atomically, and a source scan that keeps it the only one.

Every writer of the project (fluidsim's HDF5, recon's .ply/.npz/meshes/datasets, viz's PNG/MP4, nbv.io, the apps)
goes through :mod:`fluidsim.files`: a ``.fgs-<8 hex>.tmp`` file in the output's folder, renamed into place when
complete.
"""

import ast
import errno
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import fluidsim.files as fgsio_files
from fluidsim.files import (
    OutputError,
    PendingFile,
    atomic_folder,
    atomic_output,
    json_safe,
    temp_path,
    write_bytes_atomic,
    write_json_atomic,
    write_text_atomic,
)

from helpers.paths import REPO as ROOT

PACKAGES = ("fluidsim", "recon", "nbv", "viz", "apps")
SANCTIONED = {"fluidsim/files/atomic.py"}  # the only file that may rename a file into place or name a temporary file
TEMPFILE_WRITERS = {"mkstemp", "mktemp", "NamedTemporaryFile"}  # hand-made temporary files (TemporaryDirectory,
# a scratch folder removed as a whole, is not an output)


def _docstrings(tree: ast.AST) -> set[int]:
    ids = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                ids.add(id(first.value))
    return ids


def hand_written_atomic_writes(source: str) -> list[tuple[int, str]]:
    """(line, what) for each rename, hand-made temporary file or temporary-name pattern in ``source``.

    Caught: ``os.replace`` / ``os.rename`` / ``os.renames`` / ``shutil.move`` (also imported by name), any
    ``.rename(...)``, a one-argument ``.replace(x)`` (``Path.replace``; ``str.replace`` takes two), the
    ``tempfile`` functions that make a file, and a string (not a docstring) holding ``.fgs-`` or ``.tmp``.
    """
    tree = ast.parse(source)
    docs = _docstrings(tree)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module in ("os", "shutil", "tempfile"):
            for alias in node.names:
                if alias.name in {"replace", "rename", "renames", "move"} | TEMPFILE_WRITERS:
                    found.append((node.lineno, f"from {node.module} import {alias.name}"))
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            attr, owner = node.func.attr, node.func.value
            owner_name = owner.id if isinstance(owner, ast.Name) else None
            if owner_name in ("os", "shutil") and attr in ("replace", "rename", "renames", "move"):
                found.append((node.lineno, f"{owner_name}.{attr}"))
            elif attr == "rename":
                found.append((node.lineno, ".rename()"))
            elif attr == "replace" and len(node.args) == 1 and not node.keywords:
                found.append((node.lineno, ".replace(path)"))
            elif owner_name == "tempfile" and attr in TEMPFILE_WRITERS:
                found.append((node.lineno, f"tempfile.{attr}"))
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
            if ".fgs-" in node.value or ".tmp" in node.value:
                found.append((node.lineno, f"string {node.value[:30]!r}"))
    return found


def test_the_scan_catches_each_hand_written_pattern():
    bad = """
import os, shutil, tempfile
from os import replace
def f(p, q, data):
    os.replace(p, q); os.rename(p, q); shutil.move(p, q); p.rename(q); p.replace(q)
    fd, tmp = tempfile.mkstemp(dir=".")
    name = f".{q.name}.tmp"
    other = ".fgs-" + "x"
"""
    whats = [w for _, w in hand_written_atomic_writes(bad)]
    assert whats.count("os.replace") == 1 and "os.rename" in whats and "shutil.move" in whats
    assert ".rename()" in whats and ".replace(path)" in whats and "tempfile.mkstemp" in whats
    assert "from os import replace" in whats and any(".tmp" in w for w in whats) and any(".fgs-" in w for w in whats)
    fine = '''
"""Docstrings may say ``.fgs-<8 hex>.tmp`` and ``os.replace``."""
import tempfile
def g(s, p):
    with tempfile.TemporaryDirectory(dir=p) as scratch:
        return s.replace("a", "b"), str(p).replace(".", ",", 1), scratch
'''
    assert hand_written_atomic_writes(fine) == []


def test_no_module_but_fluidsim_files_writes_files_atomically_by_hand():
    offenders = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel in SANCTIONED:
                continue
            offenders += [f"{rel}:{line}: {what}" for line, what in hand_written_atomic_writes(path.read_text())]
    assert not offenders, "write outputs through fluidsim.files (or nbv.io), not by hand:\n" + "\n".join(offenders)


def test_fluidsim_files_imports_neither_taichi_nor_torch_nor_numpy():
    code = "import sys, fluidsim.files; print(sorted(m for m in ('taichi', 'torch', 'numpy') if m in sys.modules))"
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    ).stdout
    assert out.strip() == "[]"


def test_every_layer_shares_the_one_implementation():
    import nbv.io
    from fluidsim import output

    assert output.atomic_output is nbv.io.atomic_output is fgsio_files.atomic_output
    assert output.OutputError is nbv.io.OutputError is OutputError
    assert output.check_writable is nbv.io.check_writable is fgsio_files.check_writable
    assert output.temp_path is temp_path


def _listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_atomic_output_renames_on_success_and_cleans_up_on_failure(tmp_path):
    target = tmp_path / ("x" * 250 + ".json")  # a 255-byte name: the temporary name is short all the same
    with atomic_output(target) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".fgs-") and len(tmp.name) == len(".fgs-12345678.tmp")
        tmp.write_text("first")
        assert not target.exists()  # nothing at the output until the block ends
    assert target.read_text() == "first"
    with pytest.raises(RuntimeError, match="half"), atomic_output(target) as tmp:
        tmp.write_text("half of a new version")
        raise RuntimeError("half written")
    assert target.read_text() == "first" and _listing(tmp_path) == [target.name]
    with atomic_output(tmp_path / "a.png", ".png") as tmp:
        assert tmp.name.endswith(".tmp.png")
        tmp.write_bytes(b"png")


def test_an_oserror_becomes_an_output_error_that_names_the_path_and_keeps_its_errno(tmp_path, monkeypatch):
    def full_disk(src, dst):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "replace", full_disk)
    with pytest.raises(OutputError, match=r"cannot write .*out\.txt: .*No space left.*free disk space") as info:
        write_text_atomic(tmp_path / "out.txt", "text")
    assert info.value.errno == errno.ENOSPC and isinstance(info.value.__cause__, OSError)
    assert _listing(tmp_path) == []  # the temporary file went too
    with pytest.raises(OutputError) as info:
        write_bytes_atomic(tmp_path / "missing" / "out.bin", b"x")  # a folder that does not exist
    assert info.value.errno == errno.ENOENT and "missing" in str(info.value)


def test_pending_file_appears_only_on_commit(tmp_path):
    pending = PendingFile(tmp_path / "run.h5")
    pending.tmp.write_bytes(b"frames")
    assert _listing(tmp_path) == [pending.tmp.name]
    assert pending.commit() == tmp_path / "run.h5" and _listing(tmp_path) == ["run.h5"]
    other = PendingFile(tmp_path / "run.h5")
    other.tmp.write_bytes(b"dropped")
    other.discard()
    other.discard()  # twice is harmless
    assert (tmp_path / "run.h5").read_bytes() == b"frames" and _listing(tmp_path) == ["run.h5"]


def test_atomic_folder_replaces_a_whole_folder_or_leaves_it(tmp_path):
    out = tmp_path / "dataset"
    with atomic_folder(out) as tmp:
        (tmp / "a.txt").write_text("1")
        assert not out.exists()
    assert _listing(out) == ["a.txt"]
    with atomic_folder(out) as tmp:
        (tmp / "b.txt").write_text("2")
    assert _listing(out) == ["b.txt"] and _listing(tmp_path) == ["dataset"]  # the old folder is gone
    with pytest.raises(ValueError, match="bad view"), atomic_folder(out) as tmp:
        (tmp / "c.txt").write_text("3")
        raise ValueError("bad view")
    assert _listing(out) == ["b.txt"] and _listing(tmp_path) == ["dataset"]


def test_atomic_folder_replaces_a_link_to_a_folder_and_leaves_no_temporary(tmp_path):
    """A folder output that was a symbolic link to a folder: the link was moved aside and shutil.rmtree, which refuses
    links, left it behind as a `.fgs-*.tmp.old` file. The link is replaced as a file would be; its target is kept."""
    target = tmp_path / "target"
    target.mkdir()
    (target / "old.txt").write_text("0")
    (tmp_path / "out").symlink_to(target)
    with atomic_folder(tmp_path / "out") as tmp:
        (tmp / "a.txt").write_text("1")
    assert _listing(tmp_path) == ["out", "target"] and not (tmp_path / "out").is_symlink()
    assert _listing(tmp_path / "out") == ["a.txt"] and _listing(target) == ["old.txt"]


def test_atomic_files_moves_a_set_in_together_or_none(tmp_path):
    from fluidsim.files import atomic_files

    (tmp_path / "a.png").write_text("old a")
    (tmp_path / "keep.txt").write_text("mine")
    with pytest.raises(KeyboardInterrupt), atomic_files(tmp_path) as tmp:
        (tmp / "a.png").write_text("new a")
        raise KeyboardInterrupt
    assert _listing(tmp_path) == ["a.png", "keep.txt"] and (tmp_path / "a.png").read_text() == "old a"
    with atomic_files(tmp_path) as tmp:
        for name in ("a.png", "b.png"):
            (tmp / name).write_text("new")
    assert _listing(tmp_path) == ["a.png", "b.png", "keep.txt"] and (tmp_path / "a.png").read_text() == "new"


def test_json_is_strict_and_takes_numpy_scalars(tmp_path):
    data = {
        "nan": float("nan"),
        "inf": np.float32("inf"),
        "f": np.float32(1.5),
        "i": np.int64(7),
        "t": (1, 2),
        "b": True,
        "p": Path("a/b"),
        3: "key",
    }
    assert json_safe(data) == {
        "nan": None,
        "inf": None,
        "f": 1.5,
        "i": 7,
        "t": [1, 2],
        "b": True,
        "p": "a/b",
        "3": "key",
    }
    assert type(json_safe(np.int64(7))) is int and type(json_safe(np.float64(2.0))) is float
    path = write_json_atomic(tmp_path / "r.json", data)
    text = path.read_text()
    assert text.endswith("}\n") and "NaN" not in text and "Infinity" not in text
    assert json.loads(text)["i"] == 7


def test_nbv_png_and_hdf5_writers_are_atomic(tmp_path):
    import cv2
    import h5py

    from nbv.io import atomic_h5, write_atomic, write_png_atomic

    image = np.zeros((4, 6, 3), np.uint8)
    image[1, 2] = (10, 20, 30)
    write_png_atomic(tmp_path / "v.png", image)
    assert np.array_equal(cv2.imread(str(tmp_path / "v.png")), image)
    with pytest.raises(ValueError, match=r"v2\.png.*cannot encode"):
        write_png_atomic(tmp_path / "v2.png", np.zeros((4, 6, 7), np.uint8))
    with atomic_h5(tmp_path / "sub" / "r.h5") as f:  # check_writable creates the folder
        f["D"] = np.arange(3.0)
    with h5py.File(tmp_path / "sub" / "r.h5") as f:
        assert f["D"][2] == 2.0
    with pytest.raises(KeyError), atomic_h5(tmp_path / "sub" / "r.h5") as f:
        f["D"] = np.zeros(2)
        raise KeyError("stop")
    with h5py.File(tmp_path / "sub" / "r.h5") as f:
        assert f["D"].shape == (3,)
    assert write_atomic(tmp_path / "c.bin", lambda tmp: tmp.write_bytes(b"ok")).read_bytes() == b"ok"
    assert not [p for p in tmp_path.rglob("*") if p.name.startswith(".fgs-")]
