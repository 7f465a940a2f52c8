"""The Gaussians' Adam: the implementation the model uses ("foreach") gives the bits of
torch's single-tensor loop, on 1 and 2 torch threads, and after a checkpoint round trip."""

from __future__ import annotations

import pytest
import torch

from plantdreamer.pipeline import model as model_module
from plantdreamer.pipeline.model import GaussianModel
from plantdreamer.pipeline.train_config import LearningRates

N = 20_003  # not a multiple of a vector width: chunk edges are exercised


def as_built_or_single_tensor(m: GaussianModel, implementation: str) -> GaussianModel:
    """The model's Adam as built ("foreach"), or switched to torch's single-tensor loop."""
    assert m.optimizer is not None
    if implementation == "single":
        for group in m.optimizer.param_groups:
            group["foreach"] = False
    return m


def trained(gaussians, implementation: str, steps: int = 6) -> GaussianModel:
    m = as_built_or_single_tensor(GaussianModel(gaussians, LearningRates()), implementation)
    g = torch.Generator().manual_seed(5)
    for step in range(steps):
        if step == 3:  # a checkpoint round trip half-way
            saved = m.state_dict()
            m = GaussianModel(gaussians, LearningRates())
            m.load_state_dict(saved)
            as_built_or_single_tensor(m, implementation)
        for p in m.params.values():
            # Gradients of many scales, some exactly zero (as for culled Gaussians).
            grad = torch.randn(p.shape, generator=g) * 10.0 ** torch.randint(
                -8, 1, p.shape, generator=g
            )
            p.grad = torch.where(torch.rand(p.shape, generator=g) < 0.1, 0.0, grad)
        assert m.optimizer is not None
        m.optimizer.step()
    return m


@pytest.mark.parametrize("threads", [1, 2])
def test_foreach_adam_gives_the_bits_of_the_single_tensor_loop(random_gaussians, threads):
    gaussians = random_gaussians(N, degree=1, seed=4)
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        single = trained(gaussians, "single")
        foreach = trained(gaussians, "foreach")
    finally:
        torch.set_num_threads(before)
    assert all(g["foreach"] for g in foreach.optimizer.param_groups)  # type: ignore[union-attr]
    assert not any(g["foreach"] for g in single.optimizer.param_groups)  # type: ignore[union-attr]
    for name in model_module.PARAM_NAMES:
        assert torch.equal(single.params[name], foreach.params[name]), name
    first = GaussianModel(gaussians).params["means"]
    assert not torch.equal(first, foreach.params["means"])
