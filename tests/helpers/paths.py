"""Paths of the repository, computed from this file's place (tests/helpers/paths.py), so that a test module
gives the same paths wherever in ``tests/`` it sits."""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]  # the repository root: README.md, assets/, docs/
TESTS = REPO / "tests"
ASSETS = REPO / "assets"
DOCS = REPO / "docs"
TORUS = ASSETS / "torus.obj"

# The real captures used for measuring (never copied into the project): FLUIDGS_REAL_SPLATS, else shared/real-splats
# beside the repository. Tests that read them skip when they are absent.
REAL_SPLATS = Path(os.environ.get("FLUIDGS_REAL_SPLATS") or REPO.parent / "shared" / "real-splats")
BIKER_COMPRESSED_PLY = REAL_SPLATS / "biker.compressed.ply"
BIKER_SPZ = REAL_SPLATS / "biker.spz"
