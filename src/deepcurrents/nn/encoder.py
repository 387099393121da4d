"""The boundary encoder E^Γ (paper §4.3): circular 1D convolutions over a loop's vertices, then the mean.

Padded batches of loops of different lengths are handled with a mask, exactly: each real vertex's
circular neighbourhood wraps around *its own loop's* real vertices (gathered by index, never reading
padding), and the mean runs over real vertices only. The authors instead padded by repeating the last
vertex and averaged over the padding too, which makes the code depend on the batch's longest loop.
"""

from __future__ import annotations

import torch
from torch import nn


def circular_neighbours(lengths: torch.Tensor, max_len: int, kernel_size: int) -> torch.Tensor:
    """Indices of each vertex's circular neighbourhood inside its own loop.

    lengths (B,) real vertex counts, each ≥ 1. Returns (B, max_len, kernel_size) long: entry [b, i, k] =
    (i + k − kernel_size // 2) mod lengths[b]; rows i ≥ lengths[b] (padding) point at vertex 0 (they are
    masked later and never feed a real vertex).
    """
    i = torch.arange(max_len, device=lengths.device)
    offsets = torch.arange(kernel_size, device=lengths.device) - kernel_size // 2
    idx = (i[None, :, None] + offsets[None, None, :]) % lengths[:, None, None]
    return torch.where((i[None, :] < lengths[:, None])[..., None], idx, torch.zeros_like(idx))


class CircularConv1d(nn.Module):
    """A Conv1d (stride 1, circular boundary, 'same' size) applied to padded loops with a mask.

    Holds an ordinary ``nn.Conv1d`` (so weights are the usual (C_out, C_in, K) tensor) and applies it
    by gathering each vertex's circular neighbours within its loop: for an unpadded loop this equals
    ``nn.Conv1d(..., padding=K // 2, padding_mode="circular")``.
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int):
        super().__init__()
        if kernel_size % 2 != 1:
            raise ValueError("CircularConv1d needs an odd kernel size (a centred neighbourhood).")
        self.conv = nn.Conv1d(in_channels, out_channels, kernel_size)

    def forward(self, h: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
        """h (B, L, C_in), neighbours (B, L, K) from ``circular_neighbours`` → (B, L, C_out)."""
        b, length, k = neighbours.shape
        gathered = torch.gather(
            h.unsqueeze(2).expand(-1, -1, k, -1), 1,
            neighbours.unsqueeze(-1).expand(-1, -1, -1, h.shape[-1]),
        )  # (B, L, K, C_in): gathered[b, i, k] = h[b, neighbours[b, i, k]]
        return torch.einsum("blkc,ock->blo", gathered, self.conv.weight) + self.conv.bias


class BoundaryEncoder(nn.Module):
    """z_Γ = mean over the loop's vertices of conv3(relu(conv2(relu(conv1(v))))), kernels 5, 3, 3.

    Invariant to cyclic shifts of the vertices (circular convolutions commute with shifts; the mean
    forgets the order). Input: vertices (B, L, 3) padded to L, and a mask (B, L) of real vertices
    (True, real vertices first, then padding) or None when every loop has L vertices. Output: (B, channels).
    """

    def __init__(self, channels: int = 256, in_dim: int = 3, kernel_sizes: tuple[int, ...] = (5, 3, 3)):
        super().__init__()
        dims = [in_dim] + [channels] * len(kernel_sizes)
        self.convs = nn.ModuleList(
            CircularConv1d(a, b, k) for a, b, k in zip(dims[:-1], dims[1:], kernel_sizes, strict=True)
        )
        self.out_dim = channels

    def forward(self, vertices: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        b, length, _ = vertices.shape
        if mask is None:
            mask = torch.ones(b, length, dtype=torch.bool, device=vertices.device)
        lengths = mask.sum(1).clamp_min(1)
        if not torch.equal(mask, torch.arange(length, device=mask.device)[None] < lengths[:, None]):
            raise ValueError("BoundaryEncoder: the mask must mark each loop's real vertices first, padding after.")
        h = vertices
        for i, conv in enumerate(self.convs):
            h = conv(h, circular_neighbours(lengths, length, conv.conv.kernel_size[0]))
            if i < len(self.convs) - 1:  # ReLU after every layer but the last (paper)
                h = torch.relu(h)
        weights = mask.to(h.dtype).unsqueeze(-1)
        return (h * weights).sum(1) / lengths.to(h.dtype).unsqueeze(-1)
