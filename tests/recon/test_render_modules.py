"""The renderer's modules form no import cycle and import no private name of one another (issue 16, item 4).

recon.render_types holds the shared types, recon._rasterize the torch rasterizer; recon.render, recon.render_gsplat,
recon.render_reference and recon.pairs build on them. The public names stay where they were.
"""

import ast
import importlib
from pathlib import Path

import recon

RECON = Path(recon.__file__).resolve().parent
RENDERER = ("render", "render_types", "_rasterize", "render_gsplat", "render_reference", "pairs")


def _imports(path: Path) -> list[tuple[str, list[str]]]:
    """(module, names) of every relative import in ``path``, function-local ones included."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            if node.module:
                out.append((node.module, [a.name for a in node.names]))
            else:  # from . import x
                out += [(a.name, []) for a in node.names]
    return out


def _graph() -> dict[str, set[str]]:
    return {p.stem: {m.split(".")[0] for m, _ in _imports(p)} for p in RECON.glob("*.py") if p.stem != "__init__"}


def _cycle(graph: dict[str, set[str]], starts) -> list[str] | None:
    """The first import cycle reachable from ``starts`` (module names), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt) :] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(starts):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_the_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}, ["a"]) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": set()}, ["a"]) is None
    assert _cycle({"a": {"b"}, "b": set(), "c": {"d"}, "d": {"c"}}, ["a", "b"]) is None


def test_the_renderer_modules_import_each_other_without_a_cycle():
    graph = _graph()
    assert set(RENDERER) <= set(graph)
    assert _cycle(graph, RENDERER) is None, _cycle(graph, RENDERER)
    assert "render" not in graph["render_gsplat"] and "render" not in graph["_rasterize"]
    assert graph["render_types"] == set()  # the shared types depend on nothing else of recon


def test_no_renderer_module_imports_a_private_name_of_another():
    private = [
        (stem, m, n)
        for stem in RENDERER
        for m, names in _imports(RECON / f"{stem}.py")
        for n in names
        if n.startswith("_")
    ]
    assert private == [], private


def test_public_renderer_names_stay_importable():
    from recon._rasterize import Composite, build_pairs
    from recon.render_types import ALPHA_MAX, PairList, RenderOutput

    render_module = importlib.import_module("recon.render")  # recon.render is also the function

    for name in ("render", "RenderOutput", "GaussianSet", "Camera"):
        assert name in recon.__all__ and hasattr(recon, name)
    assert recon.RenderOutput is RenderOutput is render_module.RenderOutput
    assert render_module.PairList is PairList and render_module.build_pairs is build_pairs
    assert render_module.ALPHA_MAX == ALPHA_MAX == 0.99 and issubclass(Composite, object)
    for name in render_module.__all__:
        assert hasattr(render_module, name), name
