"""The trained surrogate refolded for the inner loop: the same function, cheaper on a CPU.

The inner loop asks the surrogate for 296 predictions ten thousand times per outer iteration,
always in eval mode, so the networks can be rewritten once per outer iteration into an
equivalent form that costs less:

* every batch norm is folded into the convolution or linear layer before it (eval-mode batch
  norm is an affine map per channel);
* the occupancy network's first transposed convolution, on a 1x1 input, is a linear layer;
* each stride-2 transposed convolution (kernel 4, padding 1) becomes a 3x3 convolution with four
  times the output channels followed by a pixel shuffle. Every output pixel of such a layer
  reads a 2x2 neighbourhood of the input whose kernel taps depend only on the pixel's parity,
  so the four parities are four ordinary convolutions, computed as one. Ordinary convolutions
  use oneDNN's fast kernels; transposed ones fall back to a much slower path on the CPU;
* images are kept in channels-last order, which oneDNN prefers.

For a task without grids there is no occupancy network; the predictor's folded theta branch and
head are the whole surrogate. The result is differentiable like the original, so DSAS takes its
Jacobians through it too.
Outputs equal the eager networks' to float32 rounding (``tests/surrogate``).
"""

from __future__ import annotations

import copy
import ctypes
import sys

import torch
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval, fuse_conv_bn_weights, fuse_linear_bn_eval

from hritest.surrogate.networks import OccupancyNet, PredictNet


def keep_freed_memory() -> None:
    """Lets glibc keep the memory that each forward pass frees, for the next one to reuse.

    A forward pass of 296 solutions allocates and frees activations of a few MB; by default glibc
    gives blocks that size back to the kernel at once (mmap / trim), so each pass page-faults
    them in again, which cost a quarter of the inner loop's forward time on the 2-core machine.
    Raising the two thresholds (a process-wide setting, harmless elsewhere) keeps them. Does
    nothing where the C library is not glibc.
    """
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    libc.mallopt(m_mmap_threshold, 32 << 20)  # glibc's maximum on 64-bit
    libc.mallopt(m_trim_threshold, 512 << 20)


#: For a stride-2, kernel-4, padding-1 transposed convolution: output parity -> {3x3 tap: kernel index}.
_TAPS = ({0: 3, 1: 1}, {1: 2, 2: 0})


def _transposed_as_linear(conv: nn.ConvTranspose2d, bn: nn.BatchNorm2d) -> nn.Linear:
    """A kernel-k transposed convolution of a 1x1 image is a linear map to ``cout * k * k`` values."""
    weight, bias = fuse_conv_bn_weights(
        conv.weight, conv.bias, bn.running_mean, bn.running_var, bn.eps, bn.weight, bn.bias, transpose=True
    )
    cin, cout, k, _ = weight.shape
    linear = nn.Linear(cin, cout * k * k, device=weight.device)
    with torch.no_grad():
        linear.weight.copy_(weight.permute(1, 2, 3, 0).reshape(cout * k * k, cin))
        linear.bias.copy_(bias.repeat_interleave(k * k))
    return linear


def _transposed_as_shuffle(conv: nn.ConvTranspose2d, bn: nn.BatchNorm2d) -> nn.Conv2d:
    """The 3x3 convolution whose pixel shuffle (factor 2) is ``bn(conv(x))``."""
    assert conv.stride == (2, 2) and conv.padding == (1, 1) and conv.kernel_size == (4, 4)
    weight, bias = fuse_conv_bn_weights(
        conv.weight, conv.bias, bn.running_mean, bn.running_var, bn.eps, bn.weight, bn.bias, transpose=True
    )
    cin, cout = weight.shape[:2]
    phases = weight.new_zeros((cout, 2, 2, cin, 3, 3))
    for row, row_taps in enumerate(_TAPS):
        for col, col_taps in enumerate(_TAPS):
            for ty, ky in row_taps.items():
                for tx, kx in col_taps.items():
                    phases[:, row, col, :, ty, tx] = weight[:, :, ky, kx].T
    shuffle = nn.Conv2d(cin, cout * 4, 3, padding=1, device=weight.device)
    with torch.no_grad():
        shuffle.weight.copy_(phases.reshape(cout * 4, cin, 3, 3))
        shuffle.bias.copy_(bias.repeat_interleave(4))
    return shuffle


class FastOccupancy(nn.Module):
    """:class:`OccupancyNet` in eval mode, refolded (see the module's docstring)."""

    def __init__(self, net: OccupancyNet) -> None:
        super().__init__()
        layers = list(net.layers)
        convs = [m for m in layers if isinstance(m, nn.ConvTranspose2d)]
        norms = [m for m in layers if isinstance(m, nn.BatchNorm2d)]
        self.first = _transposed_as_linear(convs[0], norms[0])
        self.channels = convs[0].out_channels
        self.ups = nn.ModuleList(
            _transposed_as_shuffle(c, n).to(memory_format=torch.channels_last) for c, n in zip(convs[1:], norms[1:])
        )

    def forward(self, theta: torch.Tensor) -> torch.Tensor:
        x = torch.relu(self.first(theta)).view(len(theta), self.channels, 4, 4)
        x = x.contiguous(memory_format=torch.channels_last)
        for i, up in enumerate(self.ups):
            x = up(x)
            if i < len(self.ups) - 1:
                x = torch.relu(x)
            x = nn.functional.pixel_shuffle(x, 2)
        return torch.log_softmax(x.flatten(2), dim=-1).view_as(x)


def _fold_sequential(layers: nn.Sequential) -> nn.Sequential:
    """Folds each ``(Conv2d | Linear, BatchNorm)`` pair of ``layers`` into one layer."""
    folded: list[nn.Module] = []
    for layer in layers:
        if isinstance(layer, nn.BatchNorm2d):
            folded[-1] = fuse_conv_bn_eval(folded[-1], layer).to(memory_format=torch.channels_last)
        elif isinstance(layer, nn.BatchNorm1d):
            folded[-1] = fuse_linear_bn_eval(folded[-1], layer)
        else:
            folded.append(layer)
    return nn.Sequential(*folded)


class FastPredict(nn.Module):
    """:class:`PredictNet` in eval mode with its batch norms folded, and ``output * scale + shift``
    folded into its last layer. Without a grid branch (no grids), ``grid`` is None, as in the net."""

    def __init__(self, net: PredictNet, *, scale: torch.Tensor, shift: torch.Tensor) -> None:
        super().__init__()
        self.theta, self.head = _fold_sequential(net.theta), _fold_sequential(net.head)
        self.grid = None if net.grid is None else _fold_sequential(net.grid)
        last = self.head[-1] = copy.deepcopy(self.head[-1])
        with torch.no_grad():
            last.weight.mul_(scale[:, None])
            last.bias.mul_(scale).add_(shift)

    forward = PredictNet.forward  # the same wiring, on the folded layers


class FastSurrogate(nn.Module):
    """``theta -> predictor(theta, occupancy(theta)) * scale + shift`` of a trained surrogate's two
    networks, refolded; ``theta -> predictor(theta, None) * scale + shift`` for a task without grids
    (``occupancy`` None). A snapshot: build a new one after training."""

    def __init__(
        self, occupancy: OccupancyNet | None, predictor: PredictNet, *, scale: torch.Tensor, shift: torch.Tensor
    ) -> None:
        super().__init__()
        if (occupancy is None) != (predictor.grid is None):
            raise ValueError("the predictor has a grid branch exactly when there is an occupancy network")
        if predictor.training or (occupancy is not None and occupancy.training):
            raise ValueError("refold the networks in eval mode: batch norm folds only with fixed statistics")
        self.occupancy = None if occupancy is None else FastOccupancy(occupancy)
        self.predictor = FastPredict(predictor, scale=scale, shift=shift)
        self.outputs = predictor.head[-1].out_features
        self.requires_grad_(False)

    def forward(self, theta: torch.Tensor) -> torch.Tensor:
        return self.predictor(theta, None if self.occupancy is None else self.occupancy(theta))
