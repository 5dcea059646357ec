"""fluidsim.lazy.lazy_exports: a name loads its submodule on first use and is cached; an unknown name is an
AttributeError; a submodule is reachable as an attribute; dir() lists the exports."""

import subprocess
import sys

import pytest

from fluidsim.lazy import lazy_exports

from helpers.paths import REPO


def test_names_load_on_first_use_and_are_cached():
    namespace = {}
    getattr_, dir_ = lazy_exports("fluidsim", {"SolverConfig": "config"}, namespace)
    from fluidsim.config import SolverConfig

    assert getattr_("SolverConfig") is SolverConfig and namespace["SolverConfig"] is SolverConfig
    assert getattr_("directions").__name__ == "fluidsim.directions"
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        getattr_("nothing")
    assert "SolverConfig" in dir_()


def _last_line(code: str) -> str:
    """The last line a fresh interpreter prints when it runs ``code`` in the repository."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO).stdout
    return out.strip().splitlines()[-1]


def test_the_packages_import_without_taichi_or_torch():
    code = (
        "import sys, fluidsim, recon, nbv, nbv.physics, nbv.active; "
        "print(sorted(m for m in ('taichi', 'torch') if m in sys.modules))"
    )
    assert _last_line(code) == "[]"


def test_an_export_is_not_shadowed_by_its_submodule():
    # recon.render (the function) lives in recon/render.py; importing that submodule (nbv.heatmap does) must not
    # replace the function by the module on the package
    code = (
        "import sys, recon, nbv.heatmap, recon.render; "
        "print(callable(recon.render), recon.render.__module__, sys.modules['recon.render'].__name__)"
    )
    assert _last_line(code) == "True recon.render recon.render"


def test_the_walls_need_no_open3d_but_a_mesh_loads_it():
    """Every probe builds its walls with fluidsim.sources; open3d (about 0.6 s) is imported on a mesh's first use."""
    code = (
        "import sys, fluidsim.sources as s; s.wall_particles([0, 0, 0], [1, 1, 1], 0.5); "
        "before = 'open3d' in sys.modules; "
        "box = s.o3d.geometry.TriangleMesh.create_box(); "
        "print(before, 'open3d' in sys.modules, int(s.points_inside_mesh(box, [[0.5, 0.5, 0.5], [2, 2, 2]]).sum()))"
    )
    assert _last_line(code) == "False True 1"
