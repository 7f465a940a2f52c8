"""The Gaussians' Adam (torch's fused implementation, as the model builds it): it is
Adam (against a float64 formula by hand), its bits do not depend on torch's thread count,
and a checkpoint round trip half-way changes no bit."""

from __future__ import annotations

import pytest
import torch

from plantdreamer.pipeline.model import gaussian_model as model_module
from plantdreamer.pipeline.model.gaussian_model import GaussianModel
from plantdreamer.pipeline.settings.train_config import LearningRates

N = 20_003  # not a multiple of a vector width: chunk edges are exercised
STEPS = 6


def gradients(m: GaussianModel, g: torch.Generator) -> dict[str, torch.Tensor]:
    """Gradients of many scales, some exactly zero (as for culled Gaussians)."""
    grads = {}
    for name, p in m.params.items():
        grad = torch.randn(p.shape, generator=g) * 10.0 ** torch.randint(
            -8, 1, p.shape, generator=g
        )
        grads[name] = torch.where(torch.rand(p.shape, generator=g) < 0.1, 0.0, grad)
    return grads


def trained(gaussians, *, threads: int = 1, round_trip: bool = False):
    """The model after STEPS Adam steps, and the gradients it was given."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        m = GaussianModel(gaussians, LearningRates())
        g = torch.Generator().manual_seed(5)
        given = []
        for step in range(STEPS):
            if round_trip and step == STEPS // 2:
                saved = m.state_dict()
                m = GaussianModel(gaussians, LearningRates())
                m.load_state_dict(saved)
            grads = gradients(m, g)
            for name, p in m.params.items():
                p.grad = grads[name]
            assert m.optimizer is not None
            m.optimizer.step()
            given.append(grads)
    finally:
        torch.set_num_threads(before)
    return m, given


def adam_by_hand(start: torch.Tensor, grads: list[torch.Tensor], lr: float, eps: float):
    """Adam (torch's defaults: betas 0.9, 0.999, no weight decay) in float64."""
    beta1, beta2 = 0.9, 0.999
    x, m, v = start.double(), torch.zeros_like(start.double()), torch.zeros_like(start.double())
    for t, grad in enumerate(grads, start=1):
        grad = grad.double()
        m = beta1 * m + (1 - beta1) * grad
        v = beta2 * v + (1 - beta2) * grad * grad
        m_hat, v_hat = m / (1 - beta1**t), v / (1 - beta2**t)
        x = x - lr * m_hat / (v_hat.sqrt() + eps)
    return x


def test_the_model_uses_fused_adam_and_it_is_adam(random_gaussians):
    gaussians = random_gaussians(N, degree=1, seed=4)
    m, given = trained(gaussians)
    assert m.optimizer is not None
    assert all(group["fused"] for group in m.optimizer.param_groups)
    start = GaussianModel(gaussians).params
    rates = LearningRates()
    lr = {
        "means": rates.means, "quats": rates.quats, "log_scales": rates.scales,
        "opacity_logits": rates.opacity, "sh_dc": rates.sh_dc, "sh_rest": rates.sh_rest,
    }  # fmt: skip
    for name in model_module.PARAM_NAMES:
        expected = adam_by_hand(start[name].detach(), [g[name] for g in given], lr[name], rates.eps)
        moved = (expected - start[name].detach().double()).abs()
        error = (m.params[name].detach().double() - expected).abs()
        # The parameter rounded to float32 once per step (half an ulp each), plus a part in
        # 1e4 of the distance moved (the float32 moments); a wrong beta, bias correction or
        # sign is off by a good part of the distance itself.
        ulps = STEPS * torch.finfo(torch.float32).eps * expected.abs()
        bound = ulps + 1e-4 * moved + 1e-12
        assert bool((error <= bound).all()), (name, float((error - bound).max()))
        assert float(moved.max()) > 0 or name == "sh_rest"


@pytest.mark.parametrize("threads", [2, 3])
def test_fused_adam_gives_the_same_bits_on_any_thread_count(random_gaussians, threads):
    gaussians = random_gaussians(N, degree=1, seed=4)
    one, _ = trained(gaussians, threads=1)
    many, _ = trained(gaussians, threads=threads)
    for name in model_module.PARAM_NAMES:
        assert torch.equal(one.params[name], many.params[name]), name


def test_a_checkpoint_round_trip_changes_no_bit(random_gaussians):
    gaussians = random_gaussians(N, degree=1, seed=4)
    straight, _ = trained(gaussians)
    resumed, _ = trained(gaussians, round_trip=True)
    for name in model_module.PARAM_NAMES:
        assert torch.equal(straight.params[name], resumed.params[name]), name
