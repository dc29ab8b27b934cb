"""The refolded surrogate is the same function as the trained networks, gradients included,
with occupancy grids and without (a task that declares none)."""

from __future__ import annotations

import pytest
import torch

from hritest.surrogate.inference import FastSurrogate
from hritest.surrogate.networks import OccupancyNet, PredictNet


def trained_looking(inputs: int, channels: int, outputs: int, seed: int) -> tuple[OccupancyNet | None, PredictNet]:
    """Networks whose batch norms have non-trivial statistics and affine parameters, as after training
    (no occupancy network for ``channels=0``, as for a task without grids)."""
    torch.manual_seed(seed)
    occupancy = OccupancyNet(inputs=inputs, channels=channels) if channels else None
    predictor = PredictNet(inputs=inputs, channels=channels, outputs=outputs)
    networks = [n for n in (occupancy, predictor) if n is not None]
    with torch.no_grad():
        for _ in range(3):
            x = torch.randn(32, inputs) * 2 + 0.5
            eager(occupancy, predictor, x)
        for module in [m for n in networks for m in n.modules()]:
            if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.5, 0.5)
    for network in networks:
        network.eval()
    return occupancy, predictor


def eager(occupancy: OccupancyNet | None, predictor: PredictNet, x: torch.Tensor) -> torch.Tensor:
    """The unfolded networks' prediction, as :class:`hritest.surrogate.model.Surrogate` makes it."""
    return predictor(x, None if occupancy is None else occupancy(x))


@pytest.mark.parametrize(("inputs", "channels", "outputs"), [(9, 1, 3), (6, 2, 3), (8, 2, 4), (5, 0, 3)])
def test_refolded_predictions_and_grids_equal_the_networks(inputs, channels, outputs):
    occupancy, predictor = trained_looking(inputs, channels, outputs, seed=inputs)
    scale, shift = torch.rand(outputs) + 0.1, torch.randn(outputs)
    fast = FastSurrogate(occupancy, predictor, scale=scale, shift=shift)
    x = torch.randn(37, inputs)
    with torch.no_grad():
        before = eager(occupancy, predictor, x)
        if channels:
            torch.testing.assert_close(fast.occupancy(x), occupancy(x), rtol=1e-4, atol=1e-5)
        else:
            assert fast.occupancy is None and fast.predictor.grid is None
        torch.testing.assert_close(fast(x), before * scale + shift, rtol=1e-4, atol=1e-5)
        torch.testing.assert_close(eager(occupancy, predictor, x), before)  # the trained networks are unchanged
    assert fast.outputs == outputs


@pytest.mark.parametrize(("inputs", "channels"), [(9, 1), (5, 0)])
def test_refolded_gradients_equal_the_networks(inputs, channels):
    occupancy, predictor = trained_looking(inputs, channels, 3, seed=1)
    scale, shift = torch.tensor([2.0, 0.5, 0.1]), torch.tensor([1.0, -1.0, 0.0])
    fast = FastSurrogate(occupancy, predictor, scale=scale, shift=shift)
    x = torch.randn(5, inputs)
    unfolded = torch.autograd.functional.jacobian(lambda v: (eager(occupancy, predictor, v) * scale + shift).sum(0), x)
    refolded = torch.autograd.functional.jacobian(lambda v: fast(v).sum(0), x)
    assert refolded.abs().max() > 0
    torch.testing.assert_close(refolded, unfolded, rtol=1e-4, atol=1e-5)


def test_refolding_a_network_in_training_mode_is_refused():
    occupancy, predictor = trained_looking(9, 1, 3, seed=2)
    with pytest.raises(ValueError, match="eval mode"):
        FastSurrogate(occupancy.train(), predictor, scale=torch.ones(3), shift=torch.zeros(3))
    _, alone = trained_looking(9, 0, 3, seed=2)
    with pytest.raises(ValueError, match="eval mode"):
        FastSurrogate(None, alone.train(), scale=torch.ones(3), shift=torch.zeros(3))


def test_a_predictor_and_occupancy_network_that_do_not_belong_together_are_refused():
    occupancy, with_grid = trained_looking(9, 1, 3, seed=3)
    _, without_grid = trained_looking(9, 0, 3, seed=3)
    for pair in ((None, with_grid), (occupancy, without_grid)):
        with pytest.raises(ValueError, match="grid branch"):
            FastSurrogate(*pair, scale=torch.ones(3), shift=torch.zeros(3))


def test_an_occupancy_network_without_channels_is_refused():
    with pytest.raises(ValueError, match="at least one grid channel"):
        OccupancyNet(inputs=4, channels=0)
