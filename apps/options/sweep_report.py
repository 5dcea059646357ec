"""What `fluidgs sweep` prints: the upfront estimate, the words for Re's length L and for C_d, and the table of the
points."""

from __future__ import annotations


def print_estimate(plan, work, seconds, calibration) -> None:
    """The upfront estimate: probe-steps and minutes per speed, and the total."""
    empty = "" if calibration.empty_step_s is None else f" ({calibration.empty_step_s:.3g} s in the empty scene)"
    print(
        f"calibration: {calibration.steps} steps of one probe took {calibration.step_s:.3g} s per probe-step{empty}, "
        f"plus {calibration.run_s:.1f} s per simulation (the solid, the setup)"
    )
    print(f"{'U m/s':>7} {'dt s':>10} {'steps':>7} {'probe-steps':>12} {'est. min':>9}")
    for st, n, sec in zip(plan, work, seconds, strict=True):
        print(f"{st.speed:>7g} {st.dt:>10.3g} {st.steps:>7} {n:>12,} {sec / 60:>9.1f}")
    print(
        f"estimate: {sum(work):,} probe-steps, about {sum(seconds) / 60:.1f} min ({sum(seconds):.0f} s) on this "
        "machine",
        flush=True,
    )


def print_points(points, other: bool) -> None:
    """One row per speed: U, Re, dt, steps, D-bar, the empty scene's D-bar, C_d, the drag (and OTHER's D-bar, the
    gap)."""
    print(
        f"{'U m/s':>7} {'Re':>10} {'dt s':>10} {'steps':>6} {'D-bar':>12} {'D-bar empty':>12} {'C_d':>6} "
        f"{'drag N':>9}" + ("  D-bar OTHER         gap" if other else "")
    )
    for p in points:
        # two digits, as far as a rerun with other float roundings reproduces them (docs/performance.md)
        extra = f" {p.dbar_other:>12.2g} {p.gap:>11.2g}" if p.dbar_other is not None else ""
        empty = "n/a" if p.dbar_empty is None else f"{p.dbar_empty:.2g}"
        cd = "n/a" if p.drag_coefficient is None else f"{p.drag_coefficient:.3g}"
        drag = "n/a" if p.drag is None else f"{p.drag:.3g}"
        print(
            f"{p.speed:>7g} {p.reynolds:>10.4g} {p.dt:>10.3g} {p.steps:>6} {p.dbar:>12.2g} {empty:>12} {cd:>6} "
            f"{drag:>9}{extra}"
        )


def length_words(source: str, probe: str) -> str:
    return {
        "object": f"the object's extent along the flow of probe {probe}",
        "domain": f"the largest extent of probe {probe}'s domain",
        "given": "given by --re-length",
    }[source]


def drag_words(point) -> str:
    if point.drag_coefficient is None:
        why = "it reported no force" if point.drag is None else "it has no inflow speed"
        return f"C_d: none for probe {point.drag_probe} ({why})"
    return (
        f"C_d = 2 F / (rho U^2 A) of probe {point.drag_probe}, the flow probe: F its time-mean drag over the second "
        f"half of each run, A = {point.area:.3g} m^2 the solid's area projected along the flow (3 digits: a step's "
        "force is noisy)"
    )
