"""eve3d.gaussians.densify: cloning, splitting, pruning, the opacity reset and the growth budget."""
import math

import torch

from eve3d.core.settings import DensifySettings
from eve3d.gaussians.densify import Densifier, reset_opacity


def constructed_model():
    """Six Gaussians whose fate under the default rules (scene scale 1) is known:
    0 small, high gradient → cloned; 1 large, high absolute gradient → split;
    2 large, high gradient but low absolute gradient → kept; 3 transparent → pruned;
    4 small, low gradient → kept; 5 small, high gradient but transparent → cloned, both pruned."""
    means = torch.arange(18, dtype=torch.float32).reshape(6, 3)
    scales = torch.tensor([0.005, 0.05, 0.05, 0.005, 0.005, 0.005])[:, None].repeat(1, 3)
    opac = torch.tensor([0.5, 0.5, 0.5, 0.001, 0.5, 0.002])
    params = {"means": means, "quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(6, 1), "log_scales": scales.log(),
              "logit_opacities": torch.log(opac / (1 - opac)), "sh0": torch.rand(6, 1, 3), "shN": torch.zeros(6, 3, 3)}
    params = {k: torch.nn.Parameter(v) for k, v in params.items()}
    optimizers = {k: torch.optim.Adam([p], lr=0.01) for k, p in params.items()}
    for p in params.values():  # one step, so that every parameter has Adam moments
        p.grad = torch.ones_like(p)
    for o in optimizers.values():
        o.step()
    return params, optimizers


def test_densify_and_prune_follow_the_rules():
    params, optimizers = constructed_model()
    d = Densifier(DensifySettings(grow_grad2d=0.0002, grow_absgrad2d=0.0008, grow_scale3d=0.01, prune_opa=0.005))
    state = d.init_state(6, n_views=4)
    state["count"][:] = 2
    state["grad2d"][:] = 2 * torch.tensor([0.001, 0.0001, 0.001, 0.0001, 0.0001, 0.001])
    state["absgrad2d"][:] = 2 * torch.tensor([0.001, 0.002, 0.0005, 0.0001, 0.0001, 0.001])
    before = {k: v.detach().clone() for k, v in params.items()}
    changed = d.refine(params, optimizers, state, step=600, scene_scale=1.0, generator=torch.Generator().manual_seed(0))
    assert changed == {"clone": 2, "split": 1, "prune": 3}  # pruned: 3, 5 and 5's clone
    # 6 + 2 clones + 1 (split: one becomes two) − 3 pruned
    assert len(params["means"]) == 6
    means = params["means"].detach()
    # survivors in order: 0, 2, 4, clone of 0, the two halves of 1
    assert torch.equal(means[:3], before["means"][[0, 2, 4]])
    assert torch.equal(means[3], before["means"][0])
    halves = params["log_scales"].detach()[4:]
    assert torch.allclose(halves, before["log_scales"][1] - math.log(1.6))
    assert ((means[4:] - before["means"][1]).norm(dim=-1) < 0.05 * 5).all()
    assert not torch.equal(means[4], means[5])
    for name, p in params.items():
        st = optimizers[name].state[p]
        assert st["exp_avg"].shape == p.shape  # moments follow the rows
        assert torch.count_nonzero(st["exp_avg"][:3]) == st["exp_avg"][:3].numel()  # survivors keep theirs
        assert torch.count_nonzero(st["exp_avg"][3:]) == 0  # new rows start at zero
    assert len(state["grad2d"]) == 6 and float(state["count"].sum()) == 0


def test_prune_by_views_and_size_and_reset_opacity():
    params, optimizers = constructed_model()
    d = Densifier(DensifySettings(prune_min_views=2, reset_every=1000, prune_scale3d=0.03))
    state = d.init_state(6, n_views=4)
    state["seen"][:, 0] = True
    state["seen"][[0, 1], 1] = True  # only 0 and 1 were seen by two views
    state["birth"][0] = 100  # too young to be judged
    mask = d.prune_mask(params, state, step=105, scene_scale=1.0)
    assert mask.tolist() == [False, False, True, True, True, True]
    mask = d.prune_mask(params, state, step=1500, scene_scale=1.0)  # after a reset: size rule on
    assert mask.tolist() == [False, True, True, True, True, True]
    low = params["logit_opacities"].detach()[3].clone()
    reset_opacity(params, optimizers, 0.01)
    assert torch.sigmoid(params["logit_opacities"].detach()).max() <= 0.01 + 1e-6
    assert params["logit_opacities"].detach()[3] == low  # already below: untouched


def test_growth_budget_keeps_the_strongest_candidates():
    params, optimizers = constructed_model()
    d = Densifier(DensifySettings(max_gaussians=7, prune_opa=0.0))  # room for one more Gaussian
    state = d.init_state(6, n_views=4)
    state["count"][:] = 1
    # candidates, by gradient over threshold: clone 5 (15×), clone 0 (5×), split 1 (2.5×)
    state["grad2d"][:] = torch.tensor([0.001, 0.0001, 0.001, 0.0001, 0.0001, 0.003])
    state["absgrad2d"][:] = torch.tensor([0.001, 0.002, 0.0005, 0.0001, 0.0001, 0.001])
    means5 = params["means"].detach()[5].clone()
    changed = d.refine(params, optimizers, state, step=600, scene_scale=1.0)
    assert changed == {"clone": 1, "split": 0, "prune": 0} and len(params["means"]) == 7
    assert torch.equal(params["means"].detach()[6], means5)
