"""The Gaussians' Adam: the implementation the model uses ("foreach") gives the bits of
torch's single-tensor loop, on 1 and 2 torch threads, and after a checkpoint round trip."""

from __future__ import annotations

import pytest
import torch

from plantdreamer.pipeline import model as model_module
from plantdreamer.pipeline.model import GaussianModel
from plantdreamer.pipeline.train_config import LearningRates

N = 20_003  # not a multiple of a vector width: chunk edges are exercised


def trained(gaussians, implementation: str, monkeypatch, steps: int = 6) -> GaussianModel:
    monkeypatch.setattr(model_module, "ADAM_IMPLEMENTATION", implementation)
    m = GaussianModel(gaussians, LearningRates())
    g = torch.Generator().manual_seed(5)
    for step in range(steps):
        if step == 3:  # a checkpoint round trip half-way
            saved = m.state_dict()
            m = GaussianModel(gaussians, LearningRates())
            m.load_state_dict(saved)
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
def test_foreach_adam_gives_the_bits_of_the_single_tensor_loop(random_gaussians, monkeypatch,
                                                               threads):  # fmt: skip
    gaussians = random_gaussians(N, degree=1, seed=4)
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        single = trained(gaussians, "single", monkeypatch)
        foreach = trained(gaussians, "foreach", monkeypatch)
    finally:
        torch.set_num_threads(before)
    assert all(g["foreach"] for g in foreach.optimizer.param_groups)  # type: ignore[union-attr]
    assert not any(g["foreach"] for g in single.optimizer.param_groups)  # type: ignore[union-attr]
    for name in model_module.PARAM_NAMES:
        assert torch.equal(single.params[name], foreach.params[name]), name
    first = GaussianModel(gaussians).params["means"]
    assert not torch.equal(first, foreach.params["means"])
