"""The README cannot rot: its Python example runs, and every package name it and the docs mention exists.

- The ```python blocks of README.md run one after the other, as a user types them, in a fresh interpreter (its
  own Taichi runtime, as a user's script has), in a scratch folder that sees the bundled ``assets/``, with the
  quick preset shortened to a few steps.
- Every ``recon.X`` / ``nbv.X`` / ``fluidsim.X`` that README.md names is a submodule or a public name (in the
  package's ``__all__``), and every dotted name under those packages in README.md and docs/*.md resolves.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import re
import subprocess
import sys

import h5py
import pytest

from helpers.paths import REPO as ROOT

README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
PACKAGES = ("recon", "nbv", "fluidsim", "viz")
# dotted names such as nbv.view_scores, recon.datasets.load_cameras, fluidsim.SolverConfig
DOTTED = re.compile(r"(?<![\w./-])(" + "|".join(PACKAGES) + r")((?:\.[A-Za-z_]\w*)+)")
# The example's probes are shortened: the point is that the code runs, not the physics (tested elsewhere).
PRELUDE = """\
import nbv
_quick = nbv.PhysicsConfig.quick.__func__
nbv.PhysicsConfig.quick = classmethod(lambda cls, **kw: _quick(cls, **{**kw, "steps": 50}))
"""


def python_blocks(text: str) -> list[str]:
    """The bodies of the ```python fenced blocks of a Markdown text, in order."""
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.M | re.S)


def dotted_names(text: str) -> set[str]:
    """Every dotted name rooted at one of our packages, without a trailing sentence dot."""
    return {m.group(1) + m.group(2) for m in DOTTED.finditer(text)}


def resolve(name: str):
    """Import ``a.b.c`` as far as it is a module, then getattr the rest; AttributeError/ImportError otherwise."""
    parts = name.split(".")
    obj = importlib.import_module(parts[0])
    path = parts[0]
    for part in parts[1:]:
        path = f"{path}.{part}"
        if hasattr(obj, "__path__") and importlib.util.find_spec(path) is not None:
            obj = importlib.import_module(path)
        else:
            obj = getattr(obj, part)
    return obj


def test_readme_has_one_python_example():
    blocks = python_blocks(README.read_text())
    assert len(blocks) == 2, "README.md should hold the ```python example and its follow-up (the two this test runs)"
    lines = [ln for ln in blocks[0].splitlines() if ln.strip()]
    assert 10 <= len(lines) <= 15, f"the README example has {len(lines)} lines; keep it to 10-15"
    assert len([ln for ln in blocks[1].splitlines() if ln.strip()]) <= 6, "keep the README's follow-up short"


def test_readme_example_runs(tmp_path):
    # every name of code the README shows in its Python section runs: both blocks, in order, in one script
    code = "".join(python_blocks(README.read_text()))
    (tmp_path / "assets").symlink_to(ROOT / "assets", target_is_directory=True)
    script = tmp_path / "example.py"
    script.write_text(PRELUDE + code)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    proc = subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, f"the README example failed:\n{proc.stdout}\n{proc.stderr[-4000:]}"
    out = proc.stdout
    dbar = re.search(r"D-bar = (\S+) m\^4/s over (\d+) Gaussians, (\d+) solid particles", out)
    assert dbar, out
    assert float(dbar.group(1)) > 0, f"no probe fluid reached the Gaussians: {out}"
    assert int(dbar.group(2)) == 17952 and int(dbar.group(3)) > 0
    best = re.search(r"best views: \[(.*)\]", out)
    assert best and len(best.group(1).split(",")) == 5, out
    renders = re.search(r"S\(T\) from renders: \[(.*)\]", out)
    assert renders and len(renders.group(1).split(",")) == 8, out
    assert re.findall(r"D-bar = (\S+)", out)[1] == re.findall(r"D-bar = (\S+)", out)[0].rstrip(), out
    with h5py.File(tmp_path / "result.h5", "r") as f:
        assert f["gaussians/D"].shape == (17952,)
        assert f.attrs["status"] == "complete"
        assert f["gaussians/D"][()].max() > 0


def test_readme_format_list_is_the_formats_table():
    from recon.formats import FORMATS, gaussians_help

    text = README.read_text()
    listed = re.search(r"It reads \(the list is `recon\.formats\.FORMATS`[^\n]*\n[^\n]*\n\n((?:- [^\n]*\n)+)", text)
    assert listed, "README.md: no format list after 'It reads'"
    items = [line[2:].rstrip(";.") for line in listed.group(1).splitlines()]
    assert items == list(FORMATS.values()), "README.md's format list differs from recon.formats.FORMATS"
    assert all(v in gaussians_help() for v in FORMATS.values())  # the commands' help prints the same table


def test_docs_quote_the_one_quick_preset():
    # --quick is defined once (nbv.physics.config.QUICK); every text that gives its values gives those
    from nbv.physics.config import QUICK

    said = re.compile(r"(\S+) (?:quick preset|`--quick`)[^.;]{0,60}?r = ([\d.]+) m(?:,| and| x| ×) (\d+) steps")
    wrong = []
    for path in [README, *DOCS, ROOT / "nbv" / "physics" / "config.py"]:
        text = re.sub(r"\s+", " ", path.read_text())
        for m in said.finditer(text):
            if m.group(1) in ("earlier", "former"):  # a record of the preset before it changed
                continue
            if (float(m.group(2)), int(m.group(3))) != (QUICK["particle_radius"], QUICK["steps"]):
                wrong.append(f"{path.name}: {m.group(0)!r}")
    assert not wrong, f"these texts give other --quick values than nbv.physics.config.QUICK {QUICK}: {wrong}"


def test_make_test_quick_names_existing_tests():
    makefile = (ROOT / "Makefile").read_text()
    quick = re.search(r"^QUICK_TESTS := (.+)$", makefile, flags=re.M)
    assert quick and "test-quick:" in makefile, "the Makefile has no test-quick target"
    missing = [p for p in quick.group(1).split() if not (ROOT / p).exists()]
    assert not missing, f"make test-quick names tests that do not exist: {missing}"


def test_readme_names_are_public():
    names = dotted_names(README.read_text())
    assert names, "README.md names no package member"
    missing = []
    for name in sorted(names):
        pkg, first = name.split(".")[:2]
        module = importlib.import_module(pkg)
        is_module = importlib.util.find_spec(f"{pkg}.{first}") is not None
        if not is_module and first not in getattr(module, "__all__", ()):
            missing.append(f"{pkg}.{first} (not in {pkg}.__all__)")
            continue
        try:
            resolve(name)
        except (ImportError, AttributeError) as exc:
            missing.append(f"{name} ({exc})")
    assert not missing, f"README.md names what the packages do not export: {missing}"


@pytest.mark.parametrize("doc", DOCS, ids=[d.name for d in DOCS])
def test_docs_names_resolve(doc):
    missing = []
    for name in sorted(dotted_names(doc.read_text())):
        try:
            resolve(name)
        except (ImportError, AttributeError) as exc:
            missing.append(f"{name} ({exc})")
    assert not missing, f"{doc.name} names what does not exist: {missing}"


def heading_anchors(text: str) -> set[str]:
    """GitHub's anchors of the Markdown headings of ``text`` (lower case, punctuation dropped, spaces -> '-')."""
    return {
        re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in re.findall(r"^#+ (.+)$", text, flags=re.M)
    }


def test_docs_links_exist():
    broken = []
    for doc in [README, ROOT / "CHANGELOG.md", *DOCS]:
        if not doc.is_file():
            continue
        for target, anchor in re.findall(r"\]\(([^)#\s]*)(?:#([^)\s]*))?\)", doc.read_text()):
            if "://" in target:
                continue
            path = doc.parent / target if target else doc
            if not path.exists():
                broken.append(f"{doc.name} -> {target}")
            elif anchor and path.suffix == ".md" and anchor not in heading_anchors(path.read_text()):
                broken.append(f"{doc.name} -> {target}#{anchor} (no such heading)")
    assert not broken, f"broken links: {broken}"


def _commands(parser, prefix: str = "fluidgs"):
    """(command line prefix, parser) for every subcommand, nested ones (bench sim, ...) included."""
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield f"{prefix} {name}", sub
                yield from _commands(sub, f"{prefix} {name}")


def test_cli_reference_names_every_command_and_option():
    from apps.cli import build_parser

    text = (ROOT / "docs" / "cli.md").read_text()
    readme = README.read_text()
    missing = []
    for command, sub in _commands(build_parser()):
        if f"`{command}`" not in text:
            missing.append(f"docs/cli.md: no `{command}`")
        top = " ".join(command.split()[:2])
        if f"`{top}" not in readme:
            missing.append(f"README.md: no `{top}` in the command table")
        for action in sub._actions:
            flags = [s for s in action.option_strings if s.startswith("--") and s != "--help"]
            if flags and not any(f"`{flag}`" in text for flag in flags):
                missing.append(f"docs/cli.md: {command} {flags[0]}")
    assert not missing, (
        "the CLI reference is out of date (add these to their command's table in docs/cli.md, "
        f"as `fluidgs CMD --help` words them): {missing}"
    )
