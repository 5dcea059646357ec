"""Where an active run's time goes: wall seconds per part, per round and for the whole run.

The parts of a selection round, in the order the round runs them:

    training  the round's training iterations (n_selected x iterations_per_view);
    visual    the visual planner's ranking (FisherRF's H of the selected and candidate views, the variance fit...);
    probes    the fluid probes on the current Gaussians (fused and physics planners only);
    scoring   the view scores: S(T) of the shortlist, and the coverage and physics part of every candidate;
    other     the rest: the planning context, rounds.json and the checkpoint.

A run adds the final training (to ``total_iterations``) to ``training``. Wall seconds are what the user waits for;
each round also records its process CPU seconds, whose ratio to the wall time shows how loaded the machine was.
"""

from __future__ import annotations

from collections.abc import Sequence

from nbv.plan.rules import FUSED

PARTS = ("training", "visual", "probes", "scoring", "other")

# The printed name of the visual part, per visual planner (nbv.plan.rules names the visual planner of a method).
VISUAL_NAMES = {"fisher": "FisherRF", "variance": "variance", "random": "random", "fvs": "FVS", "physics": "none"}


def visual_name(method: str) -> str:
    """The printed name of a method's visual part: FisherRF for ``fisher`` and every ``fisher+...`` rule."""
    visual = FUSED[method].visual if method in FUSED else method
    return VISUAL_NAMES.get(visual, visual)


def round_timing(
    *, round_seconds: float, training: float, selection: float, visual: float, probes: float, parts: float
) -> dict[str, float]:
    """The parts of one round from its measured spans (wall seconds).

    Args:
        round_seconds: the whole round. training: its training. selection: ``planner.select``, probes included.
        visual: the visual planner's share of the selection (``Selection.seconds["visual"]``).
        probes: the probe run inside the selection (0 when none ran). parts: :func:`nbv.active.loop.pick_parts`.
    Returns:
        {part: seconds} over :data:`PARTS`; ``scoring`` is the selection less its visual and probe parts, plus
        ``parts``, and ``other`` the round less everything else (clamped at 0 against clock rounding).
    """
    scoring = max(selection - visual - probes, 0.0) + parts
    seconds = {"training": training, "visual": visual, "probes": probes, "scoring": scoring}
    seconds["other"] = max(round_seconds - sum(seconds.values()), 0.0)
    return {p: float(seconds[p]) for p in PARTS}


def run_timing(rounds: Sequence[dict], final_training: float = 0.0, final_other: float = 0.0) -> dict:
    """The split of a whole run: the rounds' ``timing`` summed, plus the final training.

    Args:
        rounds: the round records of rounds.json (each with ``timing`` and ``cpu_seconds``).
        final_training: wall seconds of the final training (this session's, when resumed).
        final_other: the rest of the final phase (writing the Gaussians and the files).
    Returns:
        {"seconds": {part: s}, "share": {part: fraction of the total}, "total_seconds": s, "rounds_cpu_seconds": s}.
    """
    seconds = dict.fromkeys(PARTS, 0.0)
    cpu = 0.0
    for rec in rounds:
        for p, s in rec.get("timing", {}).items():
            seconds[p] += float(s)
        cpu += float(rec.get("cpu_seconds", 0.0))
    seconds["training"] += float(final_training)
    seconds["other"] += float(final_other)
    total = sum(seconds.values())
    share = {p: (s / total if total > 0 else 0.0) for p, s in seconds.items()}
    return {"seconds": seconds, "share": share, "total_seconds": total, "rounds_cpu_seconds": cpu}


def timing_line(timing: dict, visual: str = "visual") -> str:
    """One line: every part's seconds and share, then the total (``visual`` names the visual part).

    Example:
        >>> timing_line(run_timing([], final_training=3.0), "FisherRF")[:44]
        'time: training 3.0 s (100%), FisherRF 0.0 s '
    """
    names = {"visual": visual}
    text = ", ".join(f"{names.get(p, p)} {timing['seconds'][p]:.1f} s ({100 * timing['share'][p]:.0f}%)" for p in PARTS)
    return f"time: {text}; {timing['total_seconds']:.1f} s in all"
