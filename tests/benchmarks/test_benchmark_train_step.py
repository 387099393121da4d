"""benchmarks/train_step.py's measuring helpers against cases whose answer is known."""

from __future__ import annotations

import torch
from conftest import load_benchmark


def test_products_share_and_flop_count_see_only_the_matrix_products():
    bench = load_benchmark("train_step")
    a, b = torch.randn(256, 256), torch.randn(256, 256)
    x = torch.randn(1 << 18)
    assert bench.products_share(lambda: a @ b) > 0.9
    assert bench.products_share(lambda: torch.sin(x)) == 0.0
    share = bench.products_share(lambda: (torch.sin(x), a @ b))
    assert 0.0 < share < 1.0
    assert bench.count_flops(lambda: (torch.sin(x), a @ b, torch.addmm(a, a, b))) == 2 * 2 * 256**3
