"""The refolded surrogate is the same function as the trained networks, gradients included."""

from __future__ import annotations

import pytest
import torch

from hritest.surrogate.inference import FastSurrogate
from hritest.surrogate.networks import OccupancyNet, PredictNet


def trained_looking(inputs: int, agents: int, outputs: int, seed: int) -> tuple[OccupancyNet, PredictNet]:
    """Networks whose batch norms have non-trivial statistics and affine parameters, as after training."""
    torch.manual_seed(seed)
    occupancy = OccupancyNet(inputs=inputs, agents=agents)
    predictor = PredictNet(inputs=inputs, agents=agents, outputs=outputs)
    with torch.no_grad():
        for _ in range(3):
            x = torch.randn(32, inputs) * 2 + 0.5
            predictor(x, occupancy(x))
        for module in [*occupancy.modules(), *predictor.modules()]:
            if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.5, 0.5)
    return occupancy.eval(), predictor.eval()


@pytest.mark.parametrize(("inputs", "agents", "outputs"), [(9, 1, 3), (6, 2, 3), (8, 2, 4)])
def test_refolded_predictions_and_grids_equal_the_networks(inputs, agents, outputs):
    occupancy, predictor = trained_looking(inputs, agents, outputs, seed=inputs)
    scale, shift = torch.rand(outputs) + 0.1, torch.randn(outputs)
    fast = FastSurrogate(occupancy, predictor, scale=scale, shift=shift)
    x = torch.randn(37, inputs)
    with torch.no_grad():
        grids = occupancy(x)
        before = predictor(x, grids)
        torch.testing.assert_close(fast.occupancy(x), grids, rtol=1e-4, atol=1e-5)
        torch.testing.assert_close(fast(x), before * scale + shift, rtol=1e-4, atol=1e-5)
        torch.testing.assert_close(predictor(x, grids), before)  # the trained networks are left as they were
    assert fast.outputs == outputs


def test_refolded_gradients_equal_the_networks():
    occupancy, predictor = trained_looking(9, 1, 3, seed=1)
    scale, shift = torch.tensor([2.0, 0.5, 0.1]), torch.tensor([1.0, -1.0, 0.0])
    fast = FastSurrogate(occupancy, predictor, scale=scale, shift=shift)
    x = torch.randn(5, 9)
    eager = torch.autograd.functional.jacobian(lambda v: (predictor(v, occupancy(v)) * scale + shift).sum(0), x)
    refolded = torch.autograd.functional.jacobian(lambda v: fast(v).sum(0), x)
    torch.testing.assert_close(refolded, eager, rtol=1e-4, atol=1e-5)


def test_refolding_a_network_in_training_mode_is_refused():
    occupancy, predictor = trained_looking(9, 1, 3, seed=2)
    with pytest.raises(ValueError, match="eval mode"):
        FastSurrogate(occupancy.train(), predictor, scale=torch.ones(3), shift=torch.zeros(3))
