"""The boundary encoder: equal to PyTorch's circular Conv1d stack, exactly invariant to cyclic shifts,
and blind to padding (the mask)."""

import pytest
import torch
import torch.nn.functional as F

from deepcurrents.nn.encoder import BoundaryEncoder, circular_neighbours


def reference_encoding(enc: BoundaryEncoder, loop: torch.Tensor) -> torch.Tensor:
    """The paper's encoder written with torch's own circular padding, for one unpadded loop (M, 3)."""
    h = loop.T[None]  # (1, 3, M)
    for i, conv in enumerate(enc.convs):
        k = conv.conv.kernel_size[0]
        h = F.conv1d(F.pad(h, (k // 2, k // 2), mode="circular"), conv.conv.weight, conv.conv.bias)
        if i < len(enc.convs) - 1:
            h = torch.relu(h)
    return h.mean(-1)[0]


@pytest.fixture
def encoder():
    torch.manual_seed(1)
    return BoundaryEncoder(channels=32).double()


def test_matches_torch_circular_convolutions(encoder):
    loop = torch.randn(13, 3, dtype=torch.float64)
    torch.testing.assert_close(encoder(loop[None])[0], reference_encoding(encoder, loop), rtol=0, atol=1e-12)


def test_paper_layer_sizes():
    enc = BoundaryEncoder()
    assert [c.conv.kernel_size[0] for c in enc.convs] == [5, 3, 3]
    assert [tuple(c.conv.weight.shape) for c in enc.convs] == [(256, 3, 5), (256, 256, 3), (256, 256, 3)]
    assert enc(torch.randn(2, 9, 3)).shape == (2, 256)


def test_exactly_invariant_to_cyclic_shifts(encoder):
    loop = torch.randn(17, 3, dtype=torch.float64)
    codes = torch.stack([encoder(torch.roll(loop, s, 0)[None])[0] for s in range(17)])
    torch.testing.assert_close(codes, codes[:1].expand_as(codes), rtol=0, atol=1e-12)
    # ...but not to other permutations (it does see the order)
    perm = torch.randperm(17, generator=torch.Generator().manual_seed(0))
    assert (encoder(loop[perm][None]) - encoder(loop[None])).abs().max() > 1e-3


def test_padding_is_irrelevant(encoder):
    loops = [torch.randn(n, 3, dtype=torch.float64) for n in (5, 11, 8)]
    length = 14
    padded = torch.full((3, length, 3), 1e3, dtype=torch.float64)  # wild padding values
    mask = torch.zeros(3, length, dtype=torch.bool)
    for i, lp in enumerate(loops):
        padded[i, : len(lp)] = lp
        mask[i, : len(lp)] = True
    batch = encoder(padded, mask)
    for i, lp in enumerate(loops):
        torch.testing.assert_close(batch[i], reference_encoding(encoder, lp), rtol=0, atol=1e-12)
    padded[~mask] = -7.0  # different padding: the same codes
    torch.testing.assert_close(encoder(padded, mask), batch, rtol=0, atol=0)


def test_neighbour_indices_wrap_within_each_loop():
    idx = circular_neighbours(torch.tensor([3, 5]), 5, 3)
    assert idx[0, :3].tolist() == [[2, 0, 1], [0, 1, 2], [1, 2, 0]]
    assert idx[1, 4].tolist() == [3, 4, 0]


def test_mask_must_put_real_vertices_first(encoder):
    mask = torch.tensor([[False, True, True, True]])
    with pytest.raises(ValueError, match="real vertices first"):
        encoder(torch.randn(1, 4, 3, dtype=torch.float64), mask)
