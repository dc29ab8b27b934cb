"""The paper's two-stage surrogate networks (appendix "Surrogate Model Details").

An occupancy network turns theta, seen as an ``n x 1 x 1`` image, into one 32x32 occupancy
distribution per moving agent (transposed convolutions, log-softmax over each channel's cells);
a predictor maps theta and those predicted grids to the objective and measures. Layer sizes
are the reference's; only the input size, the channel count and the output count follow the
spec. The reference has two predictor variants (teleoperation: concatenate, then an MLP head;
collaboration: an MLP branch, then a linear head); this uses the first for every spec, since
it is the more expressive of the two and the paper treats them as one design.

A task may declare no grids (``Domain.grids`` empty). Then there is nothing for an occupancy
network to learn, and the predictor is its theta branch and head alone: the same MLP, with the
head's first layer taking the theta features only.
"""

from __future__ import annotations

import torch
from torch import nn

GRID = 32


def _up(cin: int, cout: int, *, first: bool = False, last: bool = False) -> list[nn.Module]:
    layers: list[nn.Module] = [
        nn.ConvTranspose2d(cin, cout, 4, 1, 0, bias=False)
        if first
        else nn.ConvTranspose2d(cin, cout, 4, 2, 1, bias=False),
        nn.BatchNorm2d(cout),
    ]
    return layers if last else [*layers, nn.ReLU()]


def _down(cin: int, cout: int, *, last: bool = False) -> list[nn.Module]:
    conv = nn.Conv2d(cin, cout, 4, 1, 0, bias=False) if last else nn.Conv2d(cin, cout, 4, 2, 1, bias=False)
    return [conv, nn.BatchNorm2d(cout), nn.LeakyReLU()]


class OccupancyNet(nn.Module):
    """theta -> log-probabilities of each grid's cells, ``(batch, channels, 32, 32)``: one channel
    per grid the task declares (where an agent spends its time)."""

    def __init__(self, *, inputs: int, channels: int) -> None:
        super().__init__()
        if channels < 1:  # a task without grids has no occupancy network (see the module docstring)
            raise ValueError(f"an occupancy network needs at least one grid channel, got {channels}")
        self.layers = nn.Sequential(
            *_up(inputs, 32, first=True), *_up(32, 16), *_up(16, 8), *_up(8, channels, last=True)
        )

    def forward(self, theta: torch.Tensor) -> torch.Tensor:
        logits = self.layers(theta[:, :, None, None])
        return torch.log_softmax(logits.flatten(2), dim=-1).view_as(logits)


class PredictNet(nn.Module):
    """(theta, predicted occupancy log-probabilities) -> ``outputs`` numbers (objective, measures).

    With ``channels=0`` it has no grid branch (``grid`` is None) and is called with ``occupancy=None``.
    """

    def __init__(self, *, inputs: int, channels: int, outputs: int) -> None:
        super().__init__()
        self.theta = nn.Sequential(nn.Linear(inputs, 128), nn.BatchNorm1d(128), nn.ReLU())
        self.grid = (
            nn.Sequential(
                *_down(channels, 16), *_down(16, 32), *_down(32, 64), *_down(64, 128, last=True), nn.Flatten()
            )
            if channels
            else None
        )
        self.head = nn.Sequential(
            nn.Linear(256 if channels else 128, 256),
            nn.BatchNorm1d(256),
            nn.ReLU(),
            nn.Linear(256, 128),
            nn.BatchNorm1d(128),
            nn.ReLU(),
            nn.Linear(128, outputs),
        )

    def forward(self, theta: torch.Tensor, occupancy: torch.Tensor | None) -> torch.Tensor:
        features = self.theta(theta)
        if self.grid is not None:
            features = torch.cat([features, self.grid(occupancy)], dim=1)
        return self.head(features)
