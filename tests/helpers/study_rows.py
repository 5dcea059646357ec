"""The rows of an experiment's results, as :mod:`nbv.study.tables` and :mod:`nbv.study.paired` read them."""

from __future__ import annotations


def result_row(method: str, scene: str, seed: int, psnr: float, dbar: float, kind: str = "method", **over) -> dict:
    """One run's row: SSIM 0.9, no LPIPS, Chamfer 0.1, the critical subset 1 dB below ``psnr`` at the same D-bar,
    an empty-scene D-bar of 1e-5 and one probe, -x; ``over`` replaces any key."""
    row = {
        "kind": kind,
        "scene": scene,
        "method": method,
        "seed": seed,
        "psnr": psnr,
        "ssim": 0.9,
        "lpips": None,
        "chamfer": 0.1,
        "dbar": dbar,
        "dbar_empty": 1e-5,
        "critical_psnr": psnr - 1.0,
        "critical_dbar": dbar,
        "dbar_per_direction": {"-x": dbar},
    }
    row.update(over)
    return row
