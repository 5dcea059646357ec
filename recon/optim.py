"""Adam with explicit per-parameter state, and the 3DGS position learning-rate schedule.

Kerbl et al. 2023 ("3D Gaussian Splatting", Sec. 5 and 7.1) optimise every Gaussian attribute with Adam
(Kingma & Ba 2015, Algorithm 1) at its own learning rate, and decay the position learning rate
exponentially (log-linear) from ``lr_init`` to ``lr_final``. Adaptive density control adds and removes
Gaussians between steps, so the optimiser state (first and second moments) has to be cut and grown
with the parameters: :class:`GroupedAdam` keeps that state in plain named tensors so that this surgery
is one indexing operation (:meth:`GroupedAdam.remap`) instead of edits inside ``torch.optim.Adam``.
The update is the one of ``torch.optim.Adam`` (no weight decay, no amsgrad); a test compares the two.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch


def expon_lr(
    step: int, lr_init: float, lr_final: float, max_steps: int, delay_steps: int = 0, delay_mult: float = 1.0
) -> float:
    """The 3DGS exponential (log-linear) learning-rate schedule with an optional sine warm-up delay.

    lr(t) = delay(t) * exp((1 - s) log lr_init + s log lr_final), s = clip(t / max_steps, 0, 1), with
    delay(t) = delay_mult + (1 - delay_mult) sin(pi/2 clip(t / delay_steps, 0, 1)) when delay_steps > 0,
    else 1 (the reference trainer passes no delay steps for positions, so its delay_mult has no effect).

    Args:
        step: iteration (0-based or 1-based, as the caller counts; negative steps give 0).
        lr_init, lr_final: learning rates at step 0 and at ``max_steps`` (> 0).
        max_steps: steps of the decay; the rate stays at ``lr_final`` afterwards.
        delay_steps, delay_mult: warm-up length and the factor at step 0.
    Returns:
        The learning rate.

    Example:
        >>> round(expon_lr(15000, 1.6e-4, 1.6e-6, 30000), 10)
        1.6e-05
    """
    if step < 0 or (lr_init == 0.0 and lr_final == 0.0):
        return 0.0
    if delay_steps > 0:
        delay = delay_mult + (1.0 - delay_mult) * math.sin(0.5 * math.pi * min(max(step / delay_steps, 0.0), 1.0))
    else:
        delay = 1.0
    s = min(max(step / max_steps, 0.0), 1.0)
    return delay * math.exp(math.log(lr_init) * (1.0 - s) + math.log(lr_final) * s)


@dataclass
class ParamState:
    """Adam state of one parameter tensor: its step count and its two moment tensors (same shape)."""

    step: int
    exp_avg: torch.Tensor
    exp_avg_sq: torch.Tensor


class GroupedAdam:
    """Adam over named parameter tensors, each with its own learning rate and explicit state.

    Args:
        params: name -> leaf tensor (``requires_grad`` is set here). Row i of every tensor belongs to
            Gaussian i, so density control can index all of them with one mask.
        lrs: name -> learning rate (one per name in ``params``).
        betas, eps: Adam coefficients (3DGS uses eps = 1e-15).

    Example:
        >>> adam = GroupedAdam({"x": torch.zeros(2, 3)}, {"x": 0.1})
        >>> (adam.params["x"] ** 2 - 1).sum().backward(); adam.step(); adam.zero_grad()
    """

    def __init__(
        self,
        params: dict[str, torch.Tensor],
        lrs: dict[str, float],
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-15,
    ) -> None:
        if set(params) != set(lrs):
            raise ValueError(f"GroupedAdam: learning rates given for {sorted(lrs)} but parameters are {sorted(params)}")
        if not (0.0 <= betas[0] < 1.0 and 0.0 <= betas[1] < 1.0) or not eps >= 0.0:
            raise ValueError(f"GroupedAdam: betas must lie in [0, 1) and eps >= 0, got {betas}, {eps}")
        self.betas = (float(betas[0]), float(betas[1]))
        self.eps = float(eps)
        self.lrs = {k: float(v) for k, v in lrs.items()}
        self.params: dict[str, torch.Tensor] = {}
        self.state: dict[str, ParamState] = {}
        for name, p in params.items():
            self.params[name] = p.detach().clone().requires_grad_(True)
            self.state[name] = ParamState(0, torch.zeros_like(p), torch.zeros_like(p))

    @torch.no_grad()
    def step(self, skip: tuple[str, ...] = ()) -> None:
        """One Adam update of every parameter that has a gradient (names in ``skip`` are left alone)."""
        b1, b2 = self.betas
        for name, p in self.params.items():
            if p.grad is None or name in skip:
                continue
            st = self.state[name]
            st.step += 1
            st.exp_avg.lerp_(p.grad, 1.0 - b1)
            st.exp_avg_sq.mul_(b2).addcmul_(p.grad, p.grad, value=1.0 - b2)
            step_size = self.lrs[name] / (1.0 - b1**st.step)
            denom = (st.exp_avg_sq.sqrt() / math.sqrt(1.0 - b2**st.step)).add_(self.eps)
            p.addcdiv_(st.exp_avg, denom, value=-step_size)

    def zero_grad(self) -> None:
        """Drop the gradients (set them to None)."""
        for p in self.params.values():
            p.grad = None

    @torch.no_grad()
    def remap(self, new_params: dict[str, torch.Tensor], origin: torch.Tensor) -> None:
        """Replace the parameters after density control, carrying the moments of surviving rows.

        Args:
            new_params: name -> [M, ...] new values (same names and trailing shapes as now).
            origin: [M] int64; origin[i] >= 0 is the old row that new row i continues (its moments are
                kept), -1 marks a new row (zero moments, as the reference trainer gives clones and split
                children). Step counts are kept.
        """
        if set(new_params) != set(self.params):
            raise ValueError(f"remap: parameters {sorted(new_params)} differ from {sorted(self.params)}")
        origin = origin.to(device=next(iter(self.params.values())).device, dtype=torch.long)
        carried = origin >= 0
        for name, value in new_params.items():
            old = self.params[name]
            if value.shape[0] != origin.shape[0] or value.shape[1:] != old.shape[1:]:
                raise ValueError(
                    f"remap: {name} has shape {tuple(value.shape)}, expected "
                    f"({origin.shape[0]}, *{tuple(old.shape[1:])})"
                )
            st = self.state[name]
            for key in ("exp_avg", "exp_avg_sq"):
                moment = getattr(st, key)
                fresh = torch.zeros_like(value)
                fresh[carried] = moment[origin[carried]]
                setattr(st, key, fresh)
            self.params[name] = value.detach().clone().requires_grad_(True)

    @torch.no_grad()
    def reset_state(self, name: str, value: torch.Tensor | None = None) -> None:
        """Zero the moments of parameter ``name`` (optionally replacing its value), as after an opacity reset."""
        if value is not None:
            self.params[name] = value.detach().clone().requires_grad_(True)
        st = self.state[name]
        st.exp_avg = torch.zeros_like(self.params[name])
        st.exp_avg_sq = torch.zeros_like(self.params[name])

    def state_dict(self) -> dict:
        """Parameters, learning rates and moments (detached tensors) for a checkpoint."""
        return {
            "params": {k: v.detach().clone() for k, v in self.params.items()},
            "lrs": dict(self.lrs),
            "betas": self.betas,
            "eps": self.eps,
            "state": {
                k: {"step": s.step, "exp_avg": s.exp_avg.clone(), "exp_avg_sq": s.exp_avg_sq.clone()}
                for k, s in self.state.items()
            },
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore what :meth:`state_dict` returned."""
        if set(state["params"]) != set(state["state"]) or set(state["params"]) != set(state["lrs"]):
            raise ValueError("GroupedAdam.load_state_dict: params, lrs and state name different parameter sets")
        self.betas, self.eps, self.lrs = tuple(state["betas"]), float(state["eps"]), dict(state["lrs"])
        self.params = {k: v.detach().clone().requires_grad_(True) for k, v in state["params"].items()}
        self.state = {
            k: ParamState(int(s["step"]), s["exp_avg"].clone(), s["exp_avg_sq"].clone())
            for k, s in state["state"].items()
        }
