"""The test tree stays movable: test modules may sit in any subfolder of tests/ (tests/{fluidsim,recon,nbv,viz,apps}/)
without a change. Paths come from helpers.paths or conftest fixtures, shared code from the helpers package, and
no subfolder can shadow a package of the same name."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from helpers.paths import REPO, TESTS

# The repository root found from a test file's own place: right only while the file sits directly in tests/.
PATH_FROM_OWN_PLACE = re.compile(r"Path\(__file__\)[^\n]*\.(parents\[|parent\.parent)|dirname\(__file__\)")
ALLOWED_PATH_FILES = {TESTS / "conftest.py", TESTS / "helpers" / "paths.py"}  # they never move


def _test_modules() -> list[Path]:
    return sorted(p for p in TESTS.rglob("*.py") if "helpers" not in p.relative_to(TESTS).parts)


def test_no_test_module_finds_the_repository_from_its_own_place():
    offenders = [
        f"{p.relative_to(REPO)}:{text.count(chr(10), 0, m.start()) + 1}"
        for p in _test_modules()
        if p not in ALLOWED_PATH_FILES
        for text in [p.read_text()]
        for m in PATH_FROM_OWN_PLACE.finditer(text)
    ]
    assert not offenders, f"use helpers.paths (REPO, ASSETS, TORUS, REAL_SPLATS) instead: {offenders}"


def test_test_modules_do_not_import_each_other():
    offenders = []
    for p in _test_modules():
        for node in ast.walk(ast.parse(p.read_text())):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            offenders += [
                f"{p.relative_to(REPO)}: {n}"
                for n in names
                if n.split(".")[0] in ("tests", "conftest", "format_encoders") or n.startswith("test_")
            ]
    assert not offenders, f"move shared code into tests/helpers/ and import it from there: {offenders}"


def test_no_subfolder_of_tests_is_a_package_and_names_are_unique():
    """tests/ is on sys.path: a tests/nbv/__init__.py would make ``import nbv`` find the tests. pytest's default
    import mode then needs every test module's file name to be unique."""
    inits = [p.relative_to(REPO) for p in TESTS.rglob("__init__.py") if p.parent != TESTS / "helpers"]
    assert not inits, f"no __init__.py in test folders (they would shadow the packages): {inits}"
    names = [p.name for p in _test_modules() if p.name.startswith("test_")]
    assert len(names) == len(set(names)), sorted(n for n in names if names.count(n) > 1)
