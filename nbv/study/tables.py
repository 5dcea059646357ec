"""The experiment's result tables (Markdown and CSV), the paired comparisons among them."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fluidsim.directions import DIRECTIONS
from nbv.io import write_text_atomic
from nbv.study.experiment_config import ABLATION_ORDER, PICKS, ExperimentConfig, scene_names, split_method
from nbv.study.paired import paired_table


# ---- tables ------------------------------------------------------------------------------------------
def mean_std(values: Sequence[Any]) -> tuple[float | None, float | None, int]:
    """(mean, sample std (0 for one value), n) over the finite numbers of ``values``; (None, None, 0) if none."""
    xs = [float(v) for v in values if isinstance(v, (int, float)) and math.isfinite(float(v))]
    if not xs:
        return None, None, 0
    arr = np.asarray(xs)
    return float(arr.mean()), float(arr.std(ddof=1)) if len(xs) > 1 else 0.0, len(xs)


def _cell(values: Sequence[Any]) -> str:
    """ "mean ± sample std"; the spread of one run is "n/a" (it is unmeasured, not 0)."""
    m, s, n = mean_std(values)
    if m is None:
        return "n/a"
    big = abs(m) >= 1e4 or (m != 0 and abs(m) < 1e-2)
    if n == 1:
        return f"{m:.3e} ± n/a" if big else f"{m:.4f} ± n/a"
    return f"{m:.3e} ± {s:.1e}" if big else f"{m:.4f} ± {s:.4f}"


def _cells(rs: list[dict], *keys: str) -> list[str]:
    """One :func:`_cell` per key over the runs ``rs`` (a key a row lacks counts as missing)."""
    return [_cell([r.get(k) for r in rs]) for k in keys]


def _table(title: str, header: list[str], body: list[list[str]]) -> tuple[str, str]:
    md = [f"### {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    md += ["| " + " | ".join(r) + " |" for r in body]
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(header)
    writer.writerows(body)
    return "\n".join(md) + "\n", buf.getvalue()


def _by_method(rows: list[dict], kind: str | None = "method") -> dict[str, list[dict]]:
    groups: dict[str, list[dict]] = {}
    for r in rows:
        if kind is None or r["kind"] == kind:
            groups.setdefault(r["method"], []).append(r)
    return groups


def build_tables(rows: list[dict]) -> dict[str, tuple[str, str]]:
    """The four tables as {name: (Markdown, CSV)} from the job rows (see the module docstring)."""
    methods, refs = _by_method(rows), _by_method(rows, "reference")
    tables = {
        "visual": _visual_table(methods, refs),
        "physics": _physics_table(methods, refs),
        "ablation_random": _ablation_random_table(methods),
    }
    paired = paired_table(rows)
    if paired is not None:
        header, body, summary = paired
        md, text = _table(
            "Paired: each physics pick against its planner and its controls (same scene and seed)", header, body
        )
        tables["paired"] = (md + "\n" + "\n".join(summary) + "\n", text)
    tables["ablation_direction"] = _direction_table(rows, methods, refs)
    single = {m: rs for m, rs in methods.items() if "@" in m}
    if single:
        tables["ablation_selection_direction"] = _selection_direction_table(methods, single)
    return tables


def _n(rs: list[dict]) -> str:
    return str(len(rs))


def _visual_table(methods: dict[str, list[dict]], refs: dict[str, list[dict]]) -> tuple[str, str]:
    vis_cols = ["method", "n", "PSNR (dB)", "SSIM", "LPIPS", "Chamfer (scene units)"]
    body = [[m, _n(rs), *_cells(rs, "psnr", "ssim", "lpips", "chamfer")] for m, rs in {**methods, **refs}.items()]
    return _table("Visual metrics (test views)", vis_cols, body)


def _physics_row(name: str, rs: list[dict]) -> list[str]:
    return [name, _n(rs), *_cells(rs, "dbar", "critical_psnr", "critical_dbar", "functional_error", "functional_floor")]


def _physics_table(methods: dict[str, list[dict]], refs: dict[str, list[dict]]) -> tuple[str, str]:
    phys_cols = [
        "method",
        "n",
        "D-bar (m^4/s)",
        "critical PSNR (dB)",
        "critical D-bar (m^4/s)",
        "functional error",
        "its noise floor",
    ]
    body = [_physics_row(m, rs) for m, rs in methods.items()]
    all_runs = [r for rs in methods.values() for r in rs]
    body.append(["empty scene (reference)", _n(all_runs), *_cells(all_runs, "dbar_empty"), "", "", "", ""])
    body += [_physics_row(f"many-view: {m}", rs) for m, rs in refs.items()]
    return _table("Geometry divergence D-bar (lower is better) with the references", phys_cols, body)


def _ablation_random_table(methods: dict[str, list[dict]]) -> tuple[str, str]:
    abl_cols = ["method", "shortlist", "physics pick", "n", "PSNR (dB)", "D-bar (m^4/s)", "critical D-bar (m^4/s)"]
    body = []
    for m in [m for m in ABLATION_ORDER if m in methods] + [
        m for m in methods if m not in ABLATION_ORDER and "@" not in m
    ]:
        rs = methods[m]
        visual, _, pick = m.partition("+")
        fused = pick in PICKS
        shortlist = (
            ("random K" if visual == "random" else f"{visual} top-K")
            if fused
            else ("all (random pick)" if m == "random" else "all")
        )
        physics_pick = PICKS[pick] if fused else ("yes" if m == "physics" else "no")
        body.append([m, shortlist, physics_pick, _n(rs), *_cells(rs, "psnr", "dbar", "critical_dbar")])
    return _table("Selection ablation: random vs visual shortlist, with / without physics", abl_cols, body)


def _direction_table(rows: list[dict], methods: dict[str, list[dict]], refs: dict[str, list[dict]]) -> tuple[str, str]:
    dirs = [d for d in DIRECTIONS if any((r.get("dbar_per_direction") or {}).get(d) is not None for r in rows)]
    dir_cols = ["method", "n"] + [f"D-bar {d} (m^4/s)" for d in dirs] + ["D-bar max (m^4/s)"]
    body = [
        [m, _n(rs)]
        + [_cell([(r.get("dbar_per_direction") or {}).get(d) for r in rs]) for d in dirs]
        + _cells(rs, "dbar")
        for m, rs in {**methods, **refs}.items()
    ]
    return _table("Per-direction ablation: D-bar of each probe's own D_g", dir_cols, body)


def _selection_direction_table(methods: dict[str, list[dict]], single: dict[str, list[dict]]) -> tuple[str, str]:
    """The methods whose selection reads one probe direction (``method@dir``), each after its visual planner and its
    all-probe base."""
    bases = list(dict.fromkeys(split_method(m)[0] for m in single))
    names = []
    for base in bases:
        visual = base.split("+")[0]
        names += [m for m in (visual, base) if m in methods]
        names += sorted(
            (m for m in single if split_method(m)[0] == base), key=lambda m: DIRECTIONS.index(split_method(m)[1])
        )
    cols = ["method", "selection physics", "n", "PSNR (dB)", "SSIM", "D-bar (m^4/s)", "critical D-bar (m^4/s)"]
    body = []
    for m in dict.fromkeys(names):
        base, direction = split_method(m)
        driven = direction or ("all five probes" if base.endswith("+fluid") or base == "physics" else "none")
        rs = methods[m]
        body.append([m, driven, _n(rs), *_cells(rs, "psnr", "ssim", "dbar", "critical_dbar")])
    return _table("Per-direction ablation of the selection: physics from one probe direction", cols, body)


def write_tables(rows: list[dict], config: ExperimentConfig, out: Path) -> dict[str, Any]:
    """Write OUTPUT/tables/{name}.md|.csv, OUTPUT/tables.md and the plots."""
    from viz.plots import DBAR_LABEL, bar_chart  # noqa: PLC0415 - matplotlib (~0.6 s), only for the plots

    tables = build_tables(rows)
    tdir, pdir = out / "tables", out / "plots"
    tdir.mkdir(exist_ok=True)
    pdir.mkdir(exist_ok=True)
    files = []
    for name, (md, text) in tables.items():
        files.append(write_text_atomic(tdir / f"{name}.md", md))
        files.append(write_text_atomic(tdir / f"{name}.csv", text))
    head = (
        f"# Experiment\n\nscenes: {', '.join(scene_names(config.scenes))}; methods: {', '.join(config.methods)}; "
        f"seeds: {list(config.seeds)}; preset: {config.preset}. Cells: mean ± sample std over scenes x seeds "
        "(n runs; n/a: one run has no spread).\n\n"
    )
    combined = head + "\n".join(md for md, _ in tables.values())
    files.append(write_text_atomic(out / "tables.md", combined))
    groups = {**_by_method(rows), **_by_method(rows, "reference")}
    labels = list(groups)
    for key, title, ylabel in (("psnr", "test PSNR", "PSNR (dB)"), ("dbar", "geometry divergence D-bar", DBAR_LABEL)):
        stats = [mean_std([r[key] for r in groups[m]]) for m in labels]
        files.append(
            bar_chart(
                pdir / f"{key}.png", labels, [s[0] for s in stats], [s[1] for s in stats], title=title, ylabel=ylabel
            )
        )
    dir_labels, dir_means, dir_stds = [], [], []
    for m in labels:
        for d in DIRECTIONS:
            vals = [(r.get("dbar_per_direction") or {}).get(d) for r in groups[m]]
            mean, std, n = mean_std(vals)
            if n:
                dir_labels.append(f"{m[:8]} {d}")
                dir_means.append(mean)
                dir_stds.append(std)
    if dir_labels:
        files.append(
            bar_chart(
                pdir / "dbar_direction.png",
                dir_labels,
                dir_means,
                dir_stds,
                title="D-bar per probe direction",
                ylabel=DBAR_LABEL,
                xlabel="method and probe",
                width=max(720, 60 * len(dir_labels)),
            )
        )
    return {"rows": rows, "tables": {k: md for k, (md, _) in tables.items()}, "files": [str(f) for f in files]}
