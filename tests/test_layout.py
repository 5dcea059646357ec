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


# ---- apps stay thin: short modules, short functions, and commands that do not lean on each other ----------------
APPS = REPO / "apps"
APP_MODULE_LINES = 200
APP_FUNCTION_LINES = 80
# What a command may import from apps: the shared option groups (apps/options/) and the modules that are no command
# but what every command runs on: the runtime (devices, threads, Taichi's start), the exit codes, the stop signals,
# the progress lines and the help layout. apps/cli.py, the dispatcher, imports every command.
APP_SHARED = {"options", "runtime", "taichi_runtime", "startup_watchdog", "exit_codes", "signals", "progress_log"}
APP_SHARED |= {"help_format"}


def _app_modules() -> list[Path]:
    """Every module of apps/, its subpackages (apps/options/, apps/bench/, ...) included."""
    return sorted(APPS.rglob("*.py"))


def test_app_modules_are_short():
    long = {
        str(p.relative_to(REPO)): n for p in _app_modules() if (n := len(p.read_text().splitlines())) > APP_MODULE_LINES
    }
    assert not long, f"app modules over {APP_MODULE_LINES} lines (move the logic to its library module): {long}"


def test_app_functions_are_short():
    long = [
        f"{p.relative_to(REPO)}:{node.name} {node.end_lineno - node.lineno + 1}"
        for p in _app_modules()
        for node in ast.walk(ast.parse(p.read_text()))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
        and node.end_lineno - node.lineno + 1 > APP_FUNCTION_LINES
    ]
    assert not long, f"app functions over {APP_FUNCTION_LINES} lines: {long}"


def test_no_app_imports_another():
    offenders = []
    for p in APPS.glob("*.py"):
        if p.name in ("cli.py", "__init__.py"):
            continue
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.level == 1 or (node.module or "").startswith("apps.")):
                names = [node.module] if node.module else [a.name for a in node.names]
                first = [(n.removeprefix("apps.") if node.level == 0 else n).split(".")[0] for n in names]
                offenders += [f"{p.relative_to(REPO)}: {n}" for n in first if n not in APP_SHARED]
            elif isinstance(node, ast.Import):
                offenders += [
                    f"{p.relative_to(REPO)}: {a.name}"
                    for a in node.names
                    if a.name.startswith("apps.") and a.name.split(".")[1] not in APP_SHARED
                ]
    assert not offenders, f"shared CLI pieces go to apps/options/ or the library: {offenders}"


# ---- library functions stay readable: a long one splits into named steps -----------------------------------------
LIBRARY_PACKAGES = ("fluidsim", "recon", "nbv", "viz")
LIBRARY_FUNCTION_LINES = 80
# Most library functions over LIBRARY_FUNCTION_LINES lines. Long Taichi kernels count too: splitting one into several
# kernels costs launches and compiles, so a kernel may stay long, within this bound.
LIBRARY_LONG_FUNCTIONS = 10


def test_library_functions_are_short():
    long = [
        f"{p.relative_to(REPO)}:{node.lineno} {node.name} {node.end_lineno - node.lineno + 1}"
        for package in LIBRARY_PACKAGES
        for p in sorted((REPO / package).rglob("*.py"))
        for node in ast.walk(ast.parse(p.read_text()))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
        and node.end_lineno - node.lineno + 1 > LIBRARY_FUNCTION_LINES
    ]
    assert len(long) <= LIBRARY_LONG_FUNCTIONS, (
        f"{len(long)} library functions over {LIBRARY_FUNCTION_LINES} lines (at most {LIBRARY_LONG_FUNCTIONS}; split "
        f"them into named steps): {long}"
    )


def test_nbv_tests_mirror_the_subpackages():
    """tests/nbv/<sub>/ holds the tests of nbv/<sub>/; tests of nbv's top-level modules sit in tests/nbv/ itself."""
    folders = {p.name for p in (TESTS / "nbv").iterdir() if p.is_dir() and p.name != "__pycache__"}
    packages = {p.parent.name for p in (REPO / "nbv").glob("*/__init__.py")}
    assert folders <= packages, f"folders of tests/nbv/ that name no subpackage of nbv/: {sorted(folders - packages)}"
