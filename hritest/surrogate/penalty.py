"""The inner loop's differentiable repair penalty and region guess, from the spec's constraints.

See :class:`hritest.constraints.PenaltyTerms`. The penalty is subtracted, in the repair cost's
units (not standardised), from the surrogate's (standardised) objective prediction, as in the
reference, so the inner search cannot wander off into invalid scenarios where the surrogate has
never seen data; DSAS gets its gradient through autograd. Also the reason ribs' missing solution
bounds for DQD emitters do no harm.
"""

from __future__ import annotations

import numpy as np
import torch

from hritest.constraints import PenaltyTerms


class Penalty:
    """``penalty(theta)`` (torch, differentiable) and ``regions(theta)`` (numpy, nearest region)."""

    def __init__(self, terms: PenaltyTerms, device: torch.device) -> None:
        self.terms = terms
        as_tensor = lambda a: torch.as_tensor(a, dtype=torch.float32, device=device)  # noqa: E731 - a one-line local shorthand
        self.lower, self.upper = as_tensor(terms.lower), as_tensor(terms.upper)
        self.scale = as_tensor(terms.scale)  # displacements in the repair's units
        placed = np.all(terms.columns >= 0, axis=1)
        self.objects = torch.as_tensor(terms.columns[placed], device=device)
        self.object_scale = self.scale[self.objects][:, None, :]  # (objects, 1, 2): against every region
        boxes = terms.boxes[placed]
        self.allowed = torch.as_tensor(~np.isnan(boxes[..., 0, 0]), device=device)
        self.boxes = as_tensor(np.nan_to_num(boxes))
        self.groups = [torch.as_tensor(g, device=device) for g in terms.clip_groups or []]

    def __call__(self, theta: torch.Tensor) -> torch.Tensor:
        total = torch.zeros(theta.shape[0], dtype=theta.dtype, device=theta.device)
        if self.groups:
            excess = (torch.relu(self.lower - theta) + torch.relu(theta - self.upper)) / self.scale
            for group in self.groups:
                total = total + excess[:, group].sum(dim=1) ** 2
        if len(self.objects):
            total = total + self._distances(theta).min(dim=2).values.sum(dim=1)
        return total

    def _distances(self, theta: torch.Tensor) -> torch.Tensor:
        """``(batch, objects, regions)`` squared distance of each object's centre to each region."""
        xy = theta[:, self.objects]  # (batch, objects, 2)
        lo, hi = self.boxes[..., 0], self.boxes[..., 1]  # (objects, regions, 2)
        gap = (torch.relu(lo - xy[:, :, None, :]) + torch.relu(xy[:, :, None, :] - hi)) / self.object_scale
        squared = (gap**2).sum(dim=-1)
        return torch.where(self.allowed, squared, torch.full_like(squared, torch.inf))

    def regions(self, theta: torch.Tensor) -> torch.Tensor:
        """``(batch, objects)`` index of each placed object's nearest allowed region, as floats."""
        if not len(self.objects):
            return theta.new_zeros((theta.shape[0], 0))
        return self._distances(theta).argmin(dim=2).to(theta.dtype)
