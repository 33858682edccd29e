"""Adaptive density control: clone, split, prune, opacity reset (3DGS, with AbsGS's split).

Shaped like gsplat's ``DefaultStrategy``: the policy's settings and their documented
defaults are :class:`eve3d.core.settings.DensifySettings`, and its hook
:meth:`Densifier.step_post_backward` is its only contact with the training loop (the renderer already retains the 2D means' gradient, so no
pre-backward hook is needed). The row operations (:func:`duplicate`, :func:`split`,
:func:`remove`) edit the parameter dict and each parameter's Adam state together.

Rules, at every ``refine_every`` steps in [``refine_start``, ``refine_stop``):

- the mean 2D-gradient norm g (in gsplat's NDC units, pixels × size/2) over the views that
  saw a Gaussian, and likewise the mean absolute gradient a (AbsGS) when ``absgrad``;
- **clone** small Gaussians (max scale ≤ ``grow_scale3d`` × scene scale) with g > ``grow_grad2d``;
- **split** large ones into two samples of their distribution, scales / 1.6, when
  a > ``grow_absgrad2d`` (AbsGS; g > ``grow_grad2d`` when ``absgrad`` is off);
- **prune** opacity < ``prune_opa``; after the first opacity reset also max scale >
  ``prune_scale3d`` × scene scale; and Gaussians older than two passes over the views that
  fewer than ``prune_min_views`` views have seen;
- every ``reset_every`` steps (0 = never) opacities are clamped to 2 × ``prune_opa``.
"""
from __future__ import annotations

import math

import torch

from eve3d.core.settings import DensifySettings
from eve3d.gaussians.render import RenderOutput

Params = dict[str, torch.Tensor]
Optimizers = dict[str, torch.optim.Optimizer]


def _replace_rows(params: Params, optimizers: Optimizers, param_fn, state_fn, names=None) -> None:
    """Swap each parameter (all, or ``names``) for ``param_fn(name, tensor)`` and map its
    Adam moments with ``state_fn(name, tensor)``; the optimiser keeps its step count."""
    for name in names or list(params):
        old = params[name]
        new = torch.nn.Parameter(param_fn(name, old.detach()), requires_grad=old.requires_grad)
        opt = optimizers.get(name)
        if opt is not None:
            state = opt.state.pop(old, None)
            opt.param_groups[0]["params"] = [new]
            if state is not None:
                for key, value in state.items():
                    if key != "step" and torch.is_tensor(value) and value.shape == old.shape:
                        state[key] = state_fn(name, value)
                opt.state[new] = state
        params[name] = new


def duplicate(params: Params, optimizers: Optimizers, mask: torch.Tensor) -> None:
    """Append copies of the Gaussians in ``mask``; the copies start with zero moments."""
    sel = mask.nonzero().squeeze(1)
    _replace_rows(params, optimizers, lambda _, t: torch.cat([t, t.index_select(0, sel)]),
                  lambda _, s: torch.cat([s, torch.zeros_like(s.index_select(0, sel))]))


def remove(params: Params, optimizers: Optimizers, mask: torch.Tensor, state: dict | None = None) -> None:
    """Delete the Gaussians in ``mask`` (and their rows of the densification ``state``)."""
    keep = (~mask).nonzero().squeeze(1)
    _replace_rows(params, optimizers, lambda _, t: t.index_select(0, keep), lambda _, s: s.index_select(0, keep))
    if state is not None:
        _select_state(state, keep)


def split(params: Params, optimizers: Optimizers, mask: torch.Tensor, generator: torch.Generator | None = None,
          samples: int = 2, shrink: float = 1.6) -> None:
    """Replace each Gaussian in ``mask`` by ``samples`` Gaussians placed at draws from its
    own distribution, with scales divided by ``shrink``; the new rows go to the end."""
    from eve3d.gaussians.render.projection import quat_to_rotmat

    sel = mask.nonzero().squeeze(1)
    keep = (~mask).nonzero().squeeze(1)
    scales = params["log_scales"].detach().index_select(0, sel).exp()
    rot = quat_to_rotmat(params["quats"].detach().index_select(0, sel))
    noise = torch.randn((samples, len(sel), 3), generator=generator, dtype=scales.dtype).to(scales.device)
    offsets = torch.einsum("nij,snj->sni", rot, noise * scales)

    def new_rows(name: str, t: torch.Tensor) -> torch.Tensor:
        rows = t.index_select(0, sel)
        if name == "means":
            grown = (rows[None] + offsets).reshape(-1, 3)
        elif name == "log_scales":
            grown = (rows - math.log(shrink)).repeat(samples, 1)
        else:
            grown = rows.repeat(samples, *([1] * (t.dim() - 1)))
        return torch.cat([t.index_select(0, keep), grown])

    _replace_rows(params, optimizers, new_rows,
                  lambda _, s: torch.cat([s.index_select(0, keep),
                                          torch.zeros_like(s.index_select(0, sel)).repeat(samples, *([1] * (s.dim() - 1)))]))


class Densifier:
    """The densification policy of :class:`~eve3d.core.settings.DensifySettings`: gradient
    statistics per Gaussian, then clone, split, prune and opacity reset on schedule."""

    def __init__(self, settings: DensifySettings):
        self.settings = settings

    def init_state(self, n: int, n_views: int, device=None) -> dict[str, torch.Tensor]:
        """Accumulators, one row per Gaussian (kept in the checkpoint)."""
        return {"grad2d": torch.zeros(n, device=device), "absgrad2d": torch.zeros(n, device=device),
                "count": torch.zeros(n, device=device), "seen": torch.zeros(n, n_views, dtype=torch.bool, device=device),
                "birth": torch.zeros(n, dtype=torch.long, device=device)}

    def step_post_backward(self, params: Params, optimizers: Optimizers, state: dict, step: int, out: RenderOutput,
                           view_index: int, scene_scale: float, generator: torch.Generator | None = None) -> dict:
        """Accumulate this view's statistics, then grow/prune/reset on schedule. Returns
        counts of what changed (empty when nothing did)."""
        self._accumulate(state, out, view_index)
        changed: dict[str, int] = {}
        if step >= self.settings.refine_stop:
            return changed
        if step > self.settings.refine_start and step % self.settings.refine_every == 0:
            changed = self.refine(params, optimizers, state, step, scene_scale, generator)
        if self.settings.reset_every and step % self.settings.reset_every == 0:
            reset_opacity(params, optimizers, 2 * self.settings.prune_opa)
            changed["reset"] = 1
        return changed

    def _accumulate(self, state: dict, out: RenderOutput, view_index: int) -> None:
        grad = out.means2d_grad
        if grad is None:
            return
        visible = out.visible
        size = torch.tensor([out.rgb.shape[1] / 2, out.rgb.shape[0] / 2], device=grad.device)
        state["grad2d"] += torch.where(visible, (grad * size).norm(dim=-1), 0)
        if out.absgrad is not None:
            state["absgrad2d"] += torch.where(visible, (out.absgrad.reshape(-1, 2) * size).norm(dim=-1), 0)
        state["count"] += visible.float()
        state["seen"][:, view_index] |= visible

    def refine(self, params: Params, optimizers: Optimizers, state: dict, step: int, scene_scale: float,
               generator: torch.Generator | None = None) -> dict[str, int]:
        """One grow-and-prune pass with the statistics gathered so far (then cleared)."""
        count = state["count"].clamp_min(1)
        grad = state["grad2d"] / count
        big = params["log_scales"].detach().exp().amax(-1) > self.settings.grow_scale3d * scene_scale
        split_by = state["absgrad2d"] / count if self.settings.absgrad else grad
        split_threshold = self.settings.grow_absgrad2d if self.settings.absgrad else self.settings.grow_grad2d
        clone = (grad > self.settings.grow_grad2d) & ~big
        splits = (split_by > split_threshold) & big
        room = self.settings.max_gaussians - len(grad)  # a clone or a split adds one Gaussian
        if int(clone.sum() + splits.sum()) > room:
            excess = torch.where(big, split_by / split_threshold, grad / self.settings.grow_grad2d)
            excess = torch.where(clone | splits, excess, torch.zeros_like(excess))
            chosen = torch.zeros_like(clone)
            chosen[torch.argsort(excess, descending=True)[:max(room, 0)]] = True
            clone, splits = clone & chosen, splits & chosen
        n_clone, n_split = int(clone.sum()), int(splits.sum())
        duplicate(params, optimizers, clone)
        _append_state(state, _grown_rows(state, clone.nonzero().squeeze(1), step))
        splits = torch.cat([splits, torch.zeros(n_clone, dtype=torch.bool, device=splits.device)])
        grown = _grown_rows(state, splits.nonzero().squeeze(1), step)
        split(params, optimizers, splits, generator)
        _select_state(state, (~splits).nonzero().squeeze(1))
        _append_state(state, {k: torch.cat([v, v]) for k, v in grown.items()})
        prune = self.prune_mask(params, state, step, scene_scale)
        n_prune = int(prune.sum())
        remove(params, optimizers, prune, state)
        for key in ("grad2d", "absgrad2d", "count"):
            state[key].zero_()
        return {"clone": n_clone, "split": n_split, "prune": n_prune}

    def prune_mask(self, params: Params, state: dict, step: int, scene_scale: float) -> torch.Tensor:
        """Which Gaussians the pruning rules remove now."""
        opacity = torch.sigmoid(params["logit_opacities"].detach())
        prune = opacity < self.settings.prune_opa
        if self.settings.reset_every and step > self.settings.reset_every:
            prune |= params["log_scales"].detach().exp().amax(-1) > self.settings.prune_scale3d * scene_scale
        if self.settings.prune_min_views > 0:
            n_views = state["seen"].shape[1]
            old = step - state["birth"] >= 2 * n_views
            prune |= old & (state["seen"].sum(1) < self.settings.prune_min_views)
        return prune


def _select_state(state: dict, rows: torch.Tensor) -> None:
    for key in state:
        state[key] = state[key].index_select(0, rows)


def _grown_rows(state: dict, parents: torch.Tensor, step: int) -> dict:
    """State rows for Gaussians grown from ``parents``: the visibility record is inherited,
    the gradient statistics start at zero, the birth step is ``step``."""
    rows = {k: v.index_select(0, parents) for k, v in state.items()}
    for key in ("grad2d", "absgrad2d", "count"):
        rows[key] = torch.zeros_like(rows[key])
    rows["birth"] = torch.full_like(rows["birth"], step)
    return rows


def _append_state(state: dict, rows: dict) -> None:
    for key in state:
        state[key] = torch.cat([state[key], rows[key]])


def reset_opacity(params: Params, optimizers: Optimizers, value: float) -> None:
    """Clamp every opacity to at most ``value`` and clear its Adam moments."""
    limit = math.log(value / (1 - value))
    _replace_rows(params, optimizers, lambda _, t: t.clamp_max(limit), lambda _, s: torch.zeros_like(s),
                  names=("logit_opacities",))
