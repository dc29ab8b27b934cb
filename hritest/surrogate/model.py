"""The surrogate: trains the two networks on evaluated scenarios and predicts new ones in batches.

Weights (and optimiser state) are kept between fits. A fit trains the occupancy network first
(KL divergence to the observed grids), then the predictor for the same number of epochs with the
occupancy network frozen and fed its *predicted* grids, so that at exploitation time it sees what
it was trained on; on every sample (the paper's schedule) or on given rows (the incremental one,
``search.surrogate.training``). Targets are the regularised objective divided by the objective's
range, and the raw measures, each learned standardised over all samples and mapped back. A task
that declares no grids has no occupancy network: the predictor alone learns the targets from
theta, and a fit's ``occupancy_loss`` is NaN.

The networks see theta clipped into the parameter bounds, so a prediction outside them is that of
the nearest point inside. This and the standardised targets depart from the paper's reference
code; ``docs/departures.md`` says why, with the measurements.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from hritest.surrogate.inference import FastSurrogate
from hritest.surrogate.networks import OccupancyNet, PredictNet


def pick_device(name: str) -> torch.device:
    """``auto`` is CUDA when present, else the CPU."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        from hritest.errors import HritestError

        raise HritestError("--device cuda was asked for, but torch sees no CUDA device; use --device cpu or auto")
    return torch.device(name)


@dataclass(frozen=True)
class Fit:
    """The last epoch's mean losses of one training round; NaN for a loss with nothing to train
    (``occupancy_loss`` of a surrogate without grids, either loss of a fit of zero epochs)."""

    occupancy_loss: float
    predictor_loss: float
    samples: int


class Surrogate:
    """Occupancy network + predictor, trained together on (theta, grids, targets).

    Args:
        bounds: theta's lower and upper bounds; predictions are made for theta clipped into them.
        channels: the task's grid count, ``len(domain.grids)``; 0: no occupancy network, the
            predictor learns from theta alone. outputs: 1 + number of measures.
    """

    def __init__(
        self,
        *,
        bounds: tuple[np.ndarray, np.ndarray],
        channels: int,
        outputs: int,
        epochs: int,
        batch_size: int,
        learning_rate: float,
        device: torch.device,
        seed: int,
    ) -> None:
        torch.manual_seed(seed + 42)
        self.device = device
        self.lower, self.upper = (torch.as_tensor(np.asarray(b), dtype=torch.float32, device=device) for b in bounds)
        inputs = len(self.lower)
        # In eval mode except while fit() trains them: predictions never update batch-norm statistics.
        self.occupancy = OccupancyNet(inputs=inputs, channels=channels).to(device).eval() if channels else None
        self.predictor = PredictNet(inputs=inputs, channels=channels, outputs=outputs).to(device).eval()
        # fused: one kernel over all parameters per step instead of a dozen small ops per tensor, the
        # same update to float rounding (docs/decisions.md has the timing).
        self.occupancy_optimizer = (
            None
            if self.occupancy is None
            else torch.optim.AdamW(self.occupancy.parameters(), lr=learning_rate, fused=True)
        )
        self.predictor_optimizer = torch.optim.AdamW(self.predictor.parameters(), lr=learning_rate, fused=True)
        self.epochs, self.batch_size, self.seed = epochs, batch_size, seed
        self.rounds = 0
        # The targets' standardisation, set by each fit(): prediction = network output * std + mean.
        self.target_mean = torch.zeros(outputs, device=device)
        self.target_std = torch.ones(outputs, device=device)

    def fit(
        self,
        theta: np.ndarray,
        occupancy: np.ndarray | None,
        targets: np.ndarray,
        *,
        rows: np.ndarray | None = None,
        deadline: float | None = None,
    ) -> Fit:
        """One round of training (batches of ``batch_size``, last partial dropped): on every sample,
        or only on ``rows`` of them (the networks keep what earlier rounds taught them).

        With ``deadline`` (a ``time.monotonic()`` value), each network stops at the first batch
        after its share of the time ran out (the occupancy network's is the first half), even in
        the middle of an epoch: a round then costs what the caller can spend, and the warm
        networks learn the rest later.

        ``occupancy`` is ``(samples, channels, 32, 32)``; without grids it is not read (None, or
        the ``(samples, 0, 32, 32)`` array a run directory gives). The targets are standardised
        over every sample either way, so predictions keep one scale.
        """
        generator = torch.Generator().manual_seed(self.seed + 420 + self.rounds)
        self.rounds += 1
        x = self.clip(torch.as_tensor(theta, dtype=torch.float32, device=self.device))
        y = torch.as_tensor(targets, dtype=torch.float32, device=self.device)
        self.target_mean = y.mean(dim=0)
        std = y.std(dim=0) if len(y) > 1 else torch.ones_like(self.target_mean)
        self.target_std = torch.where(std > 1e-8, std, torch.ones_like(std))  # a constant target: any scale
        y = (y - self.target_mean) / self.target_std
        if rows is not None:
            index = torch.as_tensor(rows, dtype=torch.long, device=self.device)
            x, y = x[index], y[index]
            # Indexed before converting: a run's grids are read from disk only for these rows.
            occupancy = None if occupancy is None or self.occupancy is None else np.asarray(occupancy[rows])
        batch = min(self.batch_size, len(x))  # the paper's first round has 100 samples

        occupancy_loss, predicted = math.nan, None
        halfway = None if deadline is None else (time.monotonic() + deadline) / 2
        if self.occupancy is not None:
            kl = nn.KLDivLoss(reduction="batchmean")
            grids = torch.as_tensor(np.asarray(occupancy), dtype=torch.float32, device=self.device)
            self.occupancy.train()
            occupancy_loss = self._epochs(
                generator,
                len(x),
                batch,
                self.occupancy_optimizer,
                lambda i: kl(self.occupancy(x[i]), grids[i]),
                deadline=halfway,
            )
            self.occupancy.eval()
            with torch.no_grad():
                predicted = self.occupancy(x)
        self.predictor.train()
        predictor_loss = self._epochs(
            generator,
            len(x),
            batch,
            self.predictor_optimizer,
            lambda i: nn.functional.mse_loss(self.predictor(x[i], _rows(predicted, i)), y[i]),
            deadline=deadline,
        )
        self.predictor.eval()
        return Fit(occupancy_loss, predictor_loss, len(x))

    def _epochs(
        self,
        generator: torch.Generator,
        n: int,
        batch: int,
        optimizer: torch.optim.Optimizer,
        loss_of: Callable[[torch.Tensor], torch.Tensor],
        *,
        deadline: float | None = None,
    ) -> float:
        mean = math.nan
        for _ in range(self.epochs):
            if deadline is not None and not math.isnan(mean) and time.monotonic() >= deadline:
                break
            order = torch.randperm(n, generator=generator).to(self.device)
            losses = []
            for start in range(0, n - batch + 1, batch):
                if deadline is not None and losses and time.monotonic() >= deadline:
                    break  # thousands of new samples are an epoch longer than the time given
                loss = loss_of(order[start : start + batch])
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                optimizer.step()
                losses.append(loss.detach())
            mean = float(torch.stack(losses).mean())
        return mean

    def clip(self, theta: torch.Tensor) -> torch.Tensor:
        """``theta`` clipped into the bounds: what the networks see (see the module docstring)."""
        return torch.clamp(theta, self.lower, self.upper)

    def __call__(self, theta: torch.Tensor) -> torch.Tensor:
        """Predictions ``(batch, outputs)`` for ``theta`` (a tensor on :attr:`device`), in eval mode."""
        x = self.clip(theta)
        grids = None if self.occupancy is None else self.occupancy(x)
        return self.predictor(x, grids) * self.target_std + self.target_mean

    def refolded(self) -> FastSurrogate:
        """The networks as trained now, rewritten for fast prediction (:mod:`hritest.surrogate.inference`);
        it takes theta already clipped and gives predictions in the targets' units."""
        return FastSurrogate(self.occupancy, self.predictor, scale=self.target_std, shift=self.target_mean)

    def predict(self, theta: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            x = torch.as_tensor(np.asarray(theta), dtype=torch.float32, device=self.device)
            return self(x).double().cpu().numpy()


def _rows(grids: torch.Tensor | None, index: torch.Tensor) -> torch.Tensor | None:
    """``grids[index]``, or None for a surrogate without grids."""
    return None if grids is None else grids[index]
