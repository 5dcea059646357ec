"""Charts of the experiments as PNG files, drawn with matplotlib (Agg, no display) and written atomically.

- :func:`plot_sweep`: the flow-speed study (paper Sec. 4): D-bar (paper Eq. 3 averaged over the Gaussians, m^4/s)
  against the inflow speed U (m/s, log axis), for one Gaussian set and optionally a second one, with a table of
  the Reynolds number, the CFL-constant time step and the step count per speed (``fluidgs sweep``).
- :func:`plot_drag_coefficient`: the same study's drag coefficient C_d against the Reynolds number (log axis), each
  point labelled by its inflow speed (``fluidgs sweep``).
- :func:`bar_chart`: one bar per method, mean with +-1 sample standard deviation (``fluidgs experiment``'s
  ``plots/psnr.png``, ``plots/dbar.png``, ``plots/dbar_direction.png``).

Figures are built on :class:`matplotlib.figure.Figure` with the Agg canvas, never through ``pyplot``, so no GUI
backend or global figure state is involved (safe in worker threads and on headless machines). The PNG has exactly
the requested pixel size. No Taichi or torch.

Example:
    >>> plot_sweep("sweep.png", [3, 6, 12], [1e-4, 2e-4, 5e-4], title="D-bar vs U")  # doctest: +SKIP
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.ticker import NullFormatter

from fluidsim.files import write_bytes_atomic

DPI = 100
DBAR_LABEL = "D-bar (m\N{SUPERSCRIPT FOUR}/s)"
# matplotlib's "tab10" colours, one per series or bar
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f")


def _figure(width: int, height: int, what: str) -> Figure:
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 200:
            raise ValueError(f"{what}: {name} must be an integer >= 200 pixels, got {value!r}")
    fig = Figure(figsize=(width / DPI, height / DPI), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: str | os.PathLike) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return write_bytes_atomic(path, buf.getvalue())


def _floats(values, name: str, n: int, what: str, allow_none: bool = False) -> np.ndarray:
    arr = np.array([np.nan if v is None else v for v in values], dtype=np.float64) if values is not None else None
    if arr is None or arr.shape != (n,):
        raise ValueError(f"{what}: {name} needs {n} values, got {None if arr is None else arr.shape}")
    if not allow_none and not np.isfinite(arr).all():
        raise ValueError(f"{what}: {name} must be finite, got {arr.tolist()}")
    return arr


def plot_sweep(
    path: str | os.PathLike,
    speeds: Sequence[float],
    dbar: Sequence[float],
    *,
    dbar_other: Sequence[float] | None = None,
    dbar_empty: Sequence[float] | None = None,
    reynolds: Sequence[float] | None = None,
    dts: Sequence[float] | None = None,
    steps: Sequence[int] | None = None,
    title: str = "",
    width: int = 900,
    height: int = 620,
) -> Path:
    """D-bar against the inflow speed on a log-x axis, with a table of Re, Delta t and steps; a PNG.

    Args:
        path: the .png file (written atomically).
        speeds: [S] inflow speeds U, m/s, > 0.
        dbar: [S] D-bar of the Gaussian set, m^4/s.
        dbar_other: [S] D-bar of the second set ("OTHER"), m^4/s; adds a series and a "gap" row (OTHER - D-bar).
        dbar_empty: [S] D-bar of the empty scene (no solid), m^4/s; adds a series.
        reynolds, dts, steps: [S] Re = rho U L / mu, the time step (s) and the step count per speed (table rows).
        title: figure title (default "geometry divergence vs inflow speed").
        width, height: PNG size in pixels.

    Returns:
        ``Path(path)``.
    """
    what = f"sweep plot {path}"
    us = _floats(speeds, "speeds", len(speeds), what)
    if not len(us) or not (us > 0).all():
        raise ValueError(f"{what}: needs at least one speed, all > 0 (log axis), got {us.tolist()}")
    series = [("D-bar", _floats(dbar, "dbar", len(us), what))]
    if dbar_other is not None:
        series.append(("D-bar OTHER", _floats(dbar_other, "dbar_other", len(us), what)))
    rows = [("U (m/s)", [f"{u:g}" for u in us])]
    for label, values, fmt in (
        ("Re", reynolds, "{:.3g}"),
        ("\N{GREEK CAPITAL LETTER DELTA}t (s)", dts, "{:.2e}"),
        ("steps", steps, "{:d}"),
    ):
        if values is not None:
            _floats(values, label, len(us), what)
            rows.append((label, [fmt.format(int(v) if fmt == "{:d}" else float(v)) for v in values]))
    rows.append((DBAR_LABEL, [f"{v:.3g}" for v in series[0][1]]))
    if dbar_other is not None:
        rows.append(("gap (m\N{SUPERSCRIPT FOUR}/s)", [f"{v:.3g}" for v in series[1][1] - series[0][1]]))

    if dbar_empty is not None:
        series.append(("D-bar empty scene", _floats(dbar_empty, "dbar_empty", len(us), what)))
    fig = _figure(width, height, what)
    table_h = min(0.45, 24.0 * len(rows) / height)  # figure fraction: 24 px per table row
    ax = fig.add_axes((0.11, table_h + 0.16, 0.86, 0.76 - table_h))
    for k, (name, values) in enumerate(series):
        ax.plot(us, values, marker="o", markersize=5, linewidth=2, color=PALETTE[k], label=name)
    ax.set_xscale("log")
    ax.set_xticks(us, [f"{u:g}" for u in us])  # the speeds themselves, in plain numbers
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("inflow speed U (m/s, log scale)")
    ax.set_ylabel(DBAR_LABEL)
    ax.set_title(title or "geometry divergence vs inflow speed")
    ax.set_ylim(bottom=0)
    ax.grid(True, which="both", color="#dddddd", linewidth=0.8)
    ax.legend(loc="upper left")
    table_ax = fig.add_axes((0.11, 0.02, 0.86, table_h))
    table_ax.set_axis_off()
    table = table_ax.table(
        cellText=[cells for _, cells in rows],
        rowLabels=[name for name, _ in rows],
        cellLoc="center",
        bbox=(0.0, 0.0, 1.0, 1.0),
    )
    table.auto_set_font_size(False)
    table.set_fontsize(8)
    return _save(fig, path)


def plot_drag_coefficient(
    path: str | os.PathLike,
    reynolds: Sequence[float],
    drag_coefficients: Sequence[float],
    speeds: Sequence[float],
    *,
    title: str = "",
    width: int = 900,
    height: int = 560,
) -> Path:
    """The drag coefficient C_d = 2 F / (rho U^2 A) against Re = rho U L / mu on a log-x axis, each point labelled
    by its inflow speed U; a PNG.

    Args:
        path: the .png file (written atomically).
        reynolds: [S] Reynolds numbers, finite and > 0 (log axis).
        drag_coefficients: [S] C_d, unitless, finite.
        speeds: [S] inflow speeds U, m/s (the point labels).
        title: figure title (default "drag coefficient vs Reynolds number").
        width, height: PNG size in pixels.

    Returns:
        ``Path(path)``.

    Example:
        >>> plot_drag_coefficient("cd.png", [9e2, 1.8e3], [1.1, 0.9], [3, 6])  # doctest: +SKIP
    """
    what = f"drag coefficient plot {path}"
    res = _floats(reynolds, "reynolds", len(reynolds), what)
    if not len(res) or not (res > 0).all():
        raise ValueError(f"{what}: needs at least one Reynolds number, all > 0 (log axis), got {res.tolist()}")
    cds = _floats(drag_coefficients, "drag_coefficients", len(res), what)
    us = _floats(speeds, "speeds", len(res), what)
    fig = _figure(width, height, what)
    ax = fig.add_axes((0.11, 0.12, 0.85, 0.78))
    order = np.argsort(res)
    ax.plot(res[order], cds[order], marker="o", markersize=5, linewidth=2, color=PALETTE[0])
    for k, i in enumerate(order):  # U in m/s, above and below in turn, so that neighbours on a log axis do not touch
        ax.annotate(
            f"{us[i]:g}",
            (res[i], cds[i]),
            textcoords="offset points",
            xytext=(0, 7 if k % 2 == 0 else -14),
            ha="center",
            fontsize=8,
        )
    ax.set_xscale("log")
    ax.margins(x=0.08)
    # the sweep's Reynolds numbers themselves, to 3 digits, leaving out those too close to the last one labelled
    span = max(math.log10(res.max() / res.min()), 1e-12)
    ticks: list[float] = []
    for r in res[order]:
        if not ticks or math.log10(r / ticks[-1]) >= span / 10:
            ticks.append(float(r))
    ax.set_xticks(ticks, [f"{float(f'{r:.3g}'):,.0f}" if 1 <= r < 1e6 else f"{r:.3g}" for r in ticks])
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("Reynolds number Re = \N{GREEK SMALL LETTER RHO} U L / \N{GREEK SMALL LETTER MU} (log scale)")
    ax.set_ylabel("drag coefficient C_d = 2F / (\N{GREEK SMALL LETTER RHO} U\N{SUPERSCRIPT TWO} A)")
    ax.set_title(title or "drag coefficient vs Reynolds number")
    ax.text(0.99, 0.98, "points labelled by U (m/s)", transform=ax.transAxes, ha="right", va="top", fontsize=8)
    if (cds >= 0).all():
        ax.set_ylim(bottom=0, top=1.15 * float(cds.max()) if cds.max() > 0 else None)
    ax.grid(True, which="both", color="#dddddd", linewidth=0.8)
    return _save(fig, path)


def _bars_with_whiskers(ax, x: np.ndarray, m: np.ndarray, s: np.ndarray, have: np.ndarray) -> list:
    """The bars with a value (and their +-1 std whiskers where a std is > 0) and the zero line; the legend handles."""
    colors = [PALETTE[i % len(PALETTE)] for i in range(len(x))]
    ax.bar(x[have], m[have], width=0.6, color=[c for c, h in zip(colors, have, strict=True) if h])
    handles = [Patch(facecolor="#bbbbbb", label="mean over runs")]
    if (s[have] > 0).any():
        handles.append(
            ax.errorbar(
                x[have],
                m[have],
                yerr=s[have],
                fmt="none",
                ecolor="black",
                capsize=4,
                linewidth=1,
                label="\N{PLUS-MINUS SIGN} 1 sample std",
            )
        )
    ax.axhline(0.0, color="black", linewidth=0.8)
    return handles


def _bar_values(ax, x: np.ndarray, m: np.ndarray, s: np.ndarray, have: np.ndarray) -> None:
    """Each bar's value above its whisker, and "n/a" at the foot of a bar with no value."""
    top = float(np.nanmax(np.where(have, m + s, np.nan))) if have.any() else 1.0
    for i in range(len(x)):
        if have[i]:
            ax.annotate(
                f"{m[i]:.3g}", (x[i], m[i] + s[i]), textcoords="offset points", xytext=(0, 3), ha="center", fontsize=8
            )
        else:
            ax.text(
                x[i],
                0.02 * (top if math.isfinite(top) and top > 0 else 1.0),
                "n/a",
                ha="center",
                va="bottom",
                fontsize=9,
            )


def _bar_axes(ax, x: np.ndarray, labels: Sequence[str], *, title: str, ylabel: str, xlabel: str) -> None:
    """Slanted (shortened) bar labels, the axis texts and the grid behind the bars."""
    ax.set_xticks(
        x,
        [lab if len(lab) <= 18 else lab[:17] + "\N{HORIZONTAL ELLIPSIS}" for lab in labels],
        rotation=30,
        ha="right",
        fontsize=8,
    )
    ax.set_xlim(-0.6, max(len(x), 1) - 0.4)
    ax.margins(y=0.1)  # room above the tallest bar for its value (bars stick to 0 below)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, loc="left")
    ax.grid(True, axis="y", color="#dddddd", linewidth=0.8)
    ax.set_axisbelow(True)


def bar_chart(
    path: str | os.PathLike,
    labels: Sequence[str],
    means: Sequence[float | None],
    stds: Sequence[float | None],
    *,
    title: str,
    ylabel: str,
    xlabel: str = "method",
    width: int = 720,
    height: int = 420,
) -> Path:
    """One bar per label: the mean, with a +-1 sample-std whisker; a missing mean is marked "n/a"; a PNG.

    Args:
        path: the .png file (written atomically).
        labels: [B] bar names (methods).
        means: [B] means in the unit of ``ylabel``, None where there is no value.
        stds: [B] sample standard deviations, None or 0 where there is none (one run).
        title, ylabel, xlabel: texts; ``ylabel`` names the quantity and its unit, e.g. "PSNR (dB)".
        width, height: PNG size in pixels.

    Returns:
        ``Path(path)``.
    """
    what = f"bar chart {path}"
    n = len(labels)
    m = _floats(means, "means", n, what, allow_none=True)
    s = np.nan_to_num(_floats(stds, "stds", n, what, allow_none=True), nan=0.0)
    fig = _figure(width, height, what)
    ax = fig.add_axes((0.12, 0.3, 0.84, 0.6))  # room below for slanted labels, above for title and legend
    x = np.arange(n)
    have = np.isfinite(m)
    handles = _bars_with_whiskers(ax, x, m, s, have)
    _bar_values(ax, x, m, s, have)
    _bar_axes(ax, x, labels, title=title, ylabel=ylabel, xlabel=xlabel)
    ax.legend(
        handles=handles,
        loc="lower right",
        bbox_to_anchor=(1.0, 1.0),
        ncols=len(handles),
        fontsize=8,
        frameon=False,
        borderaxespad=0.2,
    )
    return _save(fig, path)
