"""f and ∇_x f of the field MLP in one pass, with a hand-written backward (the training step's hot path).

The current loss needs ω = ∇f + α and then d(E|ω|)/dθ: a double backward. Autograd builds it from many
small nodes (each activation's backward and double backward, copies, the features' leaf gradient); here the
same maths is written out once:

forward (layers l = 1..L, a_0 = φ(x) the Fourier features, σ the activation, s_l = σ'(z_l)):
    z_l = a_{l-1} W_lᵀ + b_l,   a_l = σ(z_l),   f = a_L w_oᵀ + b_o
reverse sweep for ∇f (g_l = ∂f/∂a_l, δ_l = ∂f/∂z_l):
    g_L = w_o,   δ_l = g_l ⊙ s_l,   g_{l-1} = δ_l W_l,   ∇f = J_φ(x)ᵀ g_0
backward (given f̄ = ∂L/∂f and ω̄ = ∂L/∂∇f): first the reverse sweep's adjoint upwards,
    ḡ_0 = J_φ ω̄,   W̄_l += δ_lᵀ ḡ_{l-1},   δ̄_l = ḡ_{l-1} W_lᵀ,   ḡ_l = δ̄_l ⊙ s_l,
    z̄_l = δ̄_l ⊙ g_l ⊙ σ''(z_l),   w̄_o = Σ_n ḡ_L,
then the forward sweep's adjoint downwards (ā_L = f̄ w_o),
    z̄_l += ā_l ⊙ s_l,   W̄_l += z̄_lᵀ a_{l-1},   b̄_l = Σ_n z̄_l,   ā_{l-1} = z̄_l W_l.

That is 5 GEMMs of the first (widest) layer and 6 of each hidden one, every one of them needed (autograd also
computes the features' own gradient, a sixth wide GEMM nobody uses), plus elementwise passes over (N, width)
arrays and over the features. Their Jacobian is closed form: φ = [sin 2πBx, cos 2πBx] gives ∇f = 2π h B with
h = g_sin ⊙ cos − g_cos ⊙ sin (N, K), and its adjoint ḡ_0 = [cos ⊙ v, −sin ⊙ v] with v = 2π ω̄ Bᵀ (N, K), so the
three-column products run on (N, K) arrays (v by d broadcast passes: MKL's (N, 3) @ (3, K) is bound by writing its
output) and ḡ_0 is written once, by one broadcast pass over φ as [sin ⊙ v, cos ⊙ v]: the two products that read it
take the swap of its halves and the sign on W_1's side (``_swap_halves``). The first layer's wide arrays (φ, g_0,
ḡ_0) and h, v are kept transposed, (2K, N) and (K, N), so that every elementwise pass over them reads and writes
contiguous blocks; the products read them as transposed views at the same rate. The (2K, N) arrays' rows are padded
(``_padded_rows``): rows a power of two apart slowed the products that read them.

Why not forward-mode tangents (value and 3 tangents stacked as one (4N, width) GEMM per layer): they cost 4
GEMMs of each layer forward and 8 backward, 12 against these 5-6, and the wide first layer dominates
(paper network: 4.3 GFLOP per first-layer GEMM against 0.54 per hidden one), so it would double the FLOPs.

The parameters stay those of the same ``FieldMLP`` (checkpoints load unchanged); the activations supported
are PyTorch's Softplus (σ' = sigmoid(βz), σ'' = β σ'(1 − σ'), linear above its threshold, as autograd does)
and ReLU (σ'' = 0).
"""

from __future__ import annotations

import functools
from contextlib import contextmanager

import torch
from torch import nn
from torch.autograd.function import once_differentiable

from deepcurrents.errors import ConfigError
from deepcurrents.nn.fourier import FourierFeatures, scaled_frequencies
from deepcurrents.nn.mlp import FieldMLP


def closed_form_supported(mlp: nn.Module, encoding: nn.Module, code_dim: int = 0, extra_dim: int = 0,
                          out_dim: int = 1) -> bool:
    """Whether ``field_and_gradient`` can run ``mlp`` on ``encoding``: a ``FieldMLP`` (Linear/activation pairs,
    Softplus or ReLU, then a Linear with ``out_dim`` outputs) on ``FourierFeatures`` (enabled or the identity),
    after ``code_dim`` code inputs (a conditioned decoder, ``first_layer``) and before ``extra_dim`` features of
    another encoding (``grid``)."""
    if not isinstance(mlp, FieldMLP) or not isinstance(encoding, FourierFeatures):
        return False
    layers = list(mlp.net)
    if len(layers) < 3 or len(layers) % 2 == 0 or layers[-1].out_features != out_dim:
        return False
    if layers[0].in_features != code_dim + encoding.out_dim + extra_dim:
        return False
    return all(isinstance(lin, nn.Linear) and isinstance(act, (nn.Softplus, nn.ReLU))
               for lin, act in zip(layers[:-1:2], layers[1::2], strict=True))


def field_and_gradient(mlp: FieldMLP, encoding: FourierFeatures, x: torch.Tensor,
                       first_layer: tuple[torch.Tensor, torch.Tensor] | None = None,
                       grid: nn.Module | None = None, matmul_precision: str = "highest",
                       output_basis: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """f = mlp(encoding(x)) and ∇_x f, differentiable in the MLP's parameters (not in x).

    x: (N, d) → (f (N,), ∇f (N, d)). The same numbers as autograd (tests/nn/test_nn.py: float64, relative
    error ≤ 1e-10 on f, ∇f and every parameter gradient); f is ``mlp(encoding(x))`` up to rounding (the same
    operations, but the features are kept transposed, so the products may sum in another order).

    ``first_layer`` = (W_φ (width, F), c (S, width)): a decoder conditioned on a code per shape, whose first
    layer's code columns and bias are folded into c = W_code·code + b (computed by the caller, so its gradient
    reaches the code by autograd); x is then (S, N, d) → ((S, N), (S, N, d)), z_1 = φ W_φᵀ + c per shape.

    ``grid``: a second encoding whose features follow the Fourier features in the MLP's input, given with their
    x-Jacobian by ``grid.features_and_jacobian`` (``nn.MultiresGrid``): ∇f gains Σ_j (∂f/∂e_j) ∇e_j, and the
    backward hands the features and their Jacobian their gradients, which autograd carries on to the grid's table.

    ``matmul_precision="medium"``: when a backward follows (training), the pass's matrix products, forward and
    backward, run with bf16 (CPU, oneDNN) or TF32 (CUDA) internals where the hardware has them: faster steps, gradients
    within rounding of fp32 (docs/notes/speed.md). Evaluation
    passes (no backward) stay IEEE fp32 whatever this says.

    ``output_basis`` e (…, M), for an MLP with M outputs h: returns h (…, M) and Σ_m e_m ∇h_m (…, d), the
    gradient of f = Σ_m e_m h_m with e held fixed (``NeuralCurrent``'s phase harmonics, whose basis depends on
    x through the solid angle: the caller adds that part). The reverse sweep then starts from the per-sample
    row e W_o instead of the output weights, at no extra matrix product; e gets no gradient.
    """
    if grid is not None and first_layer is not None:
        raise ValueError("field_and_gradient: grid features are not supported with a conditioned first layer.")
    layers = list(mlp.net)
    act = layers[1]
    if isinstance(act, nn.Softplus):
        spec = ("softplus", float(act.beta), float(act.threshold))
    else:
        spec = ("relu", 1.0, 0.0)
    params = []
    for lin in layers[::2]:
        params += [lin.weight, lin.bias]
    if first_layer is not None:
        params[:2] = first_layer
    points = x.detach().reshape(-1, x.shape[-1])
    extra = extra_jac = None
    if grid is not None:
        extra, extra_jac = grid.features_and_jacobian(points)  # (P, G), (P, G, d), linear in the grid's table
    weights = encoding.feature_weights() if encoding.enabled else None
    if weights is not None:  # coarse-to-fine features: (w ⊙ φ) W_1ᵀ = φ (W_1 diag w)ᵀ; autograd carries w to W_1's grad
        if extra is not None:
            weights = torch.cat([weights, weights.new_ones(extra.shape[1])])
        params[0] = params[0] * weights
    freqs = encoding.frequencies if encoding.enabled else None
    # inside no_grad the Function still reports its inputs as needing gradients: decide here
    keep = torch.is_grad_enabled() and any(p.requires_grad for p in
                                           (*params, *((extra, extra_jac) if extra is not None else ())))
    # in the parameters' precision even under autocast (mixed-precision training): the backward's products mix
    # saved activations with the weights and need one dtype; the mass loss is sensitive to rounding anyway
    with torch.autocast(points.device.type, enabled=False):
        fast = keep and check_matmul_precision(matmul_precision) == "medium"
        basis = None if output_basis is None else output_basis.detach().reshape(points.shape[0], -1)
        f, grad = _FieldGradient.apply(points, freqs, spec, keep, fast, extra, extra_jac, basis, *params)
    if basis is not None:
        return f.reshape(*x.shape[:-1], basis.shape[1]), grad.reshape(x.shape)
    return f.reshape(x.shape[:-1]), grad.reshape(x.shape)


MATMUL_PRECISIONS = ("highest", "medium")


def network_and_gradient(mlp: FieldMLP, encoding: FourierFeatures, x: torch.Tensor, grid: nn.Module | None,
                         output_basis: torch.Tensor | None, create_graph: bool, gradient: str = "closed_form",
                         matmul_precision: str = "highest") -> tuple[torch.Tensor, torch.Tensor]:
    """f = mlp(features(x)) and ∇_x f by the hand-written pass (``field_and_gradient``) where it supports the
    network, else (or with ``gradient="autograd"``) by ``field_and_gradient_autograd``. x (N, d) → ((N,), (N, d));
    with ``output_basis`` e (N, M): (h (N, M), Σ_m e_m ∇h_m)."""
    extra_dim = grid.out_dim if grid is not None else 0
    if gradient == "closed_form" and closed_form_supported(mlp, encoding, extra_dim=extra_dim, out_dim=mlp.out_dim):
        return field_and_gradient(mlp, encoding, x, grid=grid, matmul_precision=matmul_precision,
                                  output_basis=output_basis)
    return field_and_gradient_autograd(mlp, encoding, x, grid, output_basis, create_graph)


def field_and_gradient_autograd(mlp: FieldMLP, encoding: FourierFeatures, x: torch.Tensor,
                                grid: nn.Module | None = None, output_basis: torch.Tensor | None = None,
                                create_graph: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
    """The reference for ``field_and_gradient``: autograd through the MLP to its input features, then each
    encoding's closed-form Jacobian (Fourier: 2πB cos/sin; grid: its multilinear weights' slopes); x itself only
    when the Fourier features are off. x (N, d) (detached; it may be marked for gradients) → (f (N,), ∇f (N, d)),
    or with ``output_basis`` e (N, M): (h (N, M), Σ_m e_m ∇h_m)."""
    with torch.enable_grad():
        parts, wrt = [], []
        if encoding.enabled:
            sin, cos = encoding.sin_cos(x)
            parts.append(torch.cat([sin, cos], dim=-1).requires_grad_(True))
        else:
            parts.append(x.requires_grad_(True))
        wrt.append(parts[-1])
        if grid is not None:
            grid_features, grid_jacobian = grid.features_and_jacobian(x)
            parts.append(grid_features)
            wrt.append(grid_features)
        h = mlp(torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0])
        f = h.squeeze(-1) if output_basis is None else h
        weighted = f if output_basis is None else (h * output_basis).sum(-1)
        grads = torch.autograd.grad(weighted.sum(), wrt, create_graph=create_graph)
        grad_f = encoding.input_gradient(grads[0], sin, cos) if encoding.enabled else grads[0]
        if grid is not None:
            grad_f = grad_f + torch.einsum("nk,nkd->nd", grads[1], grid_jacobian)
    if not create_graph:
        f, grad_f = f.detach(), grad_f.detach()
    return f, grad_f


def check_matmul_precision(value: str, key: str = "model.net.matmul_precision") -> str:
    """``value`` if it is a known matmul precision of the training pass, else one sentence naming ``key``."""
    if value not in MATMUL_PRECISIONS:
        raise ConfigError(f"{key}={value!r} must be one of {', '.join(MATMUL_PRECISIONS)} (highest: IEEE fp32 "
                          "products; medium: bf16 or TF32 inside fp32 products, for training only).")
    return value


@functools.cache
def reduced_precision_available(device_type: str) -> bool:
    """Whether ``matmul_precision="medium"`` has fast hardware here: bf16 matrix units on a CPU (oneDNN's
    AVX512-BF16 / AMX check), TF32 on a CUDA GPU (compute capability 8 or later)."""
    if device_type == "cpu":
        return bool(torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported())
    if device_type == "cuda":
        return torch.cuda.is_available() and torch.cuda.get_device_capability()[0] >= 8
    return False


@contextmanager
def matmul_precision_scope(device_type: str, fast: bool, exact: bool = False):
    """fp32 matrix products with reduced-precision internals while ``fast``: bf16 in oneDNN on a CPU, TF32 on
    CUDA; fp32 inputs, accumulation and outputs either way. Scoped to the pass, so that Biot–Savart (whose
    products cancel next to Γ) and every evaluation keep IEEE fp32 products. ``exact``: IEEE products inside
    a fast region (for the products with three columns: ∇f's own sum and ω̄'s spread, cheap either way)."""
    if not fast or not reduced_precision_available(device_type):
        yield
        return
    backend = torch.backends.mkldnn.matmul if device_type == "cpu" else torch.backends.cuda.matmul
    old = backend.fp32_precision
    backend.fp32_precision = "ieee" if exact else "bf16" if device_type == "cpu" else "tf32"
    try:
        yield
    finally:
        backend.fp32_precision = old


def _derivative(z: torch.Tensor, spec: tuple[str, float, float]) -> torch.Tensor:
    """σ'(z) as PyTorch's own backward computes it. (N, W) → (N, W)."""
    kind, beta, threshold = spec
    if kind == "relu":
        return (z > 0).to(z.dtype)
    s = torch.sigmoid(z if beta == 1.0 else beta * z)
    if s.dtype != torch.float32:  # in float32 sigmoid is already exactly 1 above z = 17 < threshold
        s.masked_fill_(beta * z > threshold, 1.0)
    return s


def _activation(z: torch.Tensor, spec: tuple[str, float, float]) -> torch.Tensor:
    kind, beta, threshold = spec
    if kind == "relu":
        return torch.relu(z)
    return nn.functional.softplus(z, beta, threshold)


ROW_PADDING = 64


def _padded_rows(like: torch.Tensor, rows: int, cols: int) -> torch.Tensor:
    """An uninitialised (rows, cols) array whose rows lie ``ROW_PADDING`` elements apart beyond ``cols``: the first
    layer's (2K, N) arrays. With N a power of two (the paper's 4096 samples) rows 16 KiB apart map onto the same
    cache sets, and MKL's products that read them ran slower (docs/notes/speed.md)."""
    return like.new_empty(rows, cols + ROW_PADDING)[:, :cols]


def _swap_halves(w: torch.Tensor, k: int, inverse: bool = False) -> torch.Tensor:
    """The columns [w_sin, w_cos, w_rest] of a (W, 2K + G) array as [−w_cos, w_sin, w_rest], so that
    [sin ⊙ v, cos ⊙ v] @ swap(w)ᵀ = [cos ⊙ v, −sin ⊙ v] @ wᵀ; ``inverse``: [w_cos, −w_sin, w_rest]. A new,
    contiguous array (w may be a transposed view)."""
    out = w.new_empty(w.shape)
    if inverse:
        out[:, :k] = w[:, k:2 * k]
        torch.neg(w[:, :k], out=out[:, k:2 * k])
    else:
        torch.neg(w[:, k:2 * k], out=out[:, :k])
        out[:, k:2 * k] = w[:, :k]
    out[:, 2 * k:] = w[:, 2 * k:]
    return out


class _FieldGradient(torch.autograd.Function):
    """(x, B or None, spec, keep, fast, e or None, J_e or None, E or None, W_1, b_1, …, W_L, b_L, w_o, b_o) ↦
    (f (N,), ∇f (N, d)), or (h (N, M), Σ_m E_m ∇h_m) with an output basis E (N, M) for M outputs;
    see the module doc. ``keep``: a backward will follow (training), so keep what it needs. b_1 may be (S, W):
    one bias per group of N / S consecutive rows (a conditioned decoder). ``fast``: the matrix products with
    reduced-precision internals (``matmul_precision_scope``), forward and backward. e (N, G) are extra features after
    the Fourier features (or after x), J_e (N, G, d) their x-Jacobian."""

    @staticmethod
    def forward(ctx, x, freqs, spec, keep, fast, extra, extra_jac, basis, *params):
        ctx.fast, ctx.device_type = fast, x.device.type
        with matmul_precision_scope(x.device.type, fast):
            return _FieldGradient._forward(ctx, x, freqs, spec, keep, extra, extra_jac, basis, *params)

    @staticmethod
    def _forward(ctx, x, freqs, spec, keep, extra, extra_jac, basis, *params):
        weights, biases = params[0::2], params[1::2]
        depth = len(weights) - 1
        width = 0 if extra is None else extra.shape[1]
        if freqs is not None:
            k = freqs.shape[0]
            base = 2 * k
            scaled = scaled_frequencies(freqs)  # 2π Bᵀ (d, K)
            # the first layer's (N, 2K) arrays live transposed, φᵀ (2K, N), so that sin and cos write, and h and ḡ_0
            # read, contiguous (K, N) blocks (ATen's vectorised sin into the strided half of an (N, 2K) array is
            # slower); the products take φ as a transposed view at the same rate (docs/notes/speed.md)
            proj = scaled.T @ x.T  # (K, N)
            a_t = _padded_rows(x, base + width, x.shape[0])
            torch.sin(proj, out=a_t[:k])
            torch.cos(proj, out=a_t[k:base])
            del proj
            if extra is not None:
                a_t[base:] = extra.T
            a = a_t.T
        else:
            base = x.shape[1]
            a = x if extra is None else torch.cat([x, extra], dim=1)
        inputs, derivs = [], []
        for w, b in zip(weights[:-1], biases[:-1], strict=True):
            if b.dim() == 2:  # one bias per shape, added as FamilyCurrent.decode adds it
                z = (a @ w.T).view(b.shape[0], -1, b.shape[1]).add_(b[:, None]).view(a.shape[0], -1)
            else:
                z = torch.addmm(b, a, w.T)
            inputs.append(a)
            derivs.append(_derivative(z, spec))
            a = _activation(z, spec)
            del z
        inputs.append(a)
        f = torch.addmm(biases[-1], a, weights[-1].T)
        if basis is None:
            f = f.squeeze(-1)
        # the reverse sweep: δ_l = g_l ⊙ s_l, g_{l-1} = δ_l W_l
        deltas, curvatures = [None] * depth, [None] * depth
        # g_L = w_o, (1, W), broadcast over the rows; with a basis, Σ_m E_m w_o,m per row, (N, W)
        g = weights[-1] if basis is None else basis @ weights[-1]
        for layer in reversed(range(depth)):
            s = derivs[layer]
            deltas[layer] = g * s
            if keep and spec[0] == "softplus":
                # z̄_l's factor g_l ⊙ σ''(z_l) = β g s (1 − s) = β (δ − s δ), one pass
                curvature = torch.addcmul(deltas[layer], s, deltas[layer], value=-1.0)
                curvatures[layer] = curvature.mul_(spec[1]) if spec[1] != 1.0 else curvature
            if layer == 0 and freqs is not None:  # g_0ᵀ = W_1ᵀ δ_1ᵀ (2K + G, N), in φᵀ's layout
                g = torch.mm(weights[0].T, deltas[0].T, out=_padded_rows(x, weights[0].shape[1], x.shape[0])).T
            else:
                g = deltas[layer] @ weights[layer]
        g_extra = None
        if extra is not None:  # ∇f gains Σ_j g_j ∇e_j: (N, 1, G) @ (N, G, d)
            g_extra = g[:, base:].contiguous()
            extra_grad = torch.bmm(g_extra.unsqueeze(1), extra_jac).squeeze(1)
        if freqs is not None:  # ∇f = 2π h B with h = g_sin ⊙ cos − g_cos ⊙ sin, as hᵀ (K, N)
            g_t = g.T
            h_t = g_t[:k] * a_t[k:base]
            h_t.addcmul_(g_t[k:base], a_t[:k], value=-1.0)
            # (2πBᵀ) hᵀ (d, N), both contiguous: MKL's fast layout for a three-row output (several times faster than
            # the products with hᵀ as a transposed view; docs/notes/speed.md)
            with matmul_precision_scope(x.device.type, ctx.fast, exact=True):
                grad = (scaled @ h_t).T.contiguous()  # (N, d) as callers expect; a small copy
            del h_t, g_t
        else:
            grad = g[:, :base] if extra is not None else g
        if extra is not None:
            grad = grad + extra_grad
        del g
        if keep:
            ctx.depth, ctx.rff, ctx.extra, ctx.basis = depth, freqs is not None, extra is not None, basis is not None
            ctx.base = base
            ctx.save_for_backward(*([freqs] if freqs is not None else []), *([basis] if basis is not None else []),
                                  *((extra_jac, g_extra) if extra is not None else ()), *params, *inputs,
                                  *derivs, *deltas, *(c for c in curvatures if c is not None))
        ctx.set_materialize_grads(False)
        return f, grad

    @staticmethod
    @once_differentiable
    def backward(ctx, f_bar, grad_bar):
        with matmul_precision_scope(ctx.device_type, ctx.fast):
            return _FieldGradient._backward(ctx, f_bar, grad_bar)

    @staticmethod
    def _backward(ctx, f_bar, grad_bar):
        depth = ctx.depth
        saved = list(ctx.saved_tensors)
        freqs = saved.pop(0) if ctx.rff else None
        basis = saved.pop(0) if ctx.basis else None
        extra_jac, g_extra = (saved.pop(0), saved.pop(0)) if ctx.extra else (None, None)
        base = ctx.base
        params, saved = saved[:2 * depth + 2], saved[2 * depth + 2:]
        weights, biases = params[0::2], params[1::2]
        inputs, saved = saved[:depth + 1], saved[depth + 1:]
        derivs, deltas, curvatures = saved[:depth], saved[depth:2 * depth], saved[2 * depth:]
        w_bar: list[torch.Tensor | None] = [None] * (depth + 1)
        jac_bar = extra_bar = None
        z_bar: list[torch.Tensor | None] = [None] * depth
        if grad_bar is not None:
            # the reverse sweep's adjoint, from the features up: ḡ_0 = J_φ ω̄ = 2π [cos ⊙ ω̄Bᵀ, −sin ⊙ ω̄Bᵀ]
            omega_bar = grad_bar.unsqueeze(-1)
            swapped = freqs is not None
            if swapped:
                k = freqs.shape[0]
                phi_t = inputs[0].T  # φᵀ (2K + G, N), rows padded (the forward's layout)
                # vᵀ = 2π B ω̄ᵀ (K, N) as d broadcast passes: MKL's product with an inner dimension of three is
                # bound by writing its output, and these passes write vᵀ once
                scaled = scaled_frequencies(freqs)
                omega_t = grad_bar.T.contiguous()  # (d, N)
                v_t = scaled[0][:, None] * omega_t[0]
                for c in range(1, scaled.shape[0]):
                    v_t.addcmul_(scaled[c][:, None], omega_t[c])
                # ḡ_0 = [cos ⊙ v, −sin ⊙ v] is written as its halves swapped and unsigned, [sin ⊙ v, cos ⊙ v], and
                # transposed like φ: one broadcast pass over φᵀ; the two products that read it take the swap and
                # the sign on their (W, 2K) sides instead (_swap_halves)
                g_bar_t = _padded_rows(v_t, base + (0 if extra_jac is None else extra_jac.shape[1]), v_t.shape[1])
                torch.mul(phi_t[:base].unflatten(0, (2, k)), v_t, out=g_bar_t[:base].unflatten(0, (2, k)))
                del v_t
                if extra_jac is not None:  # ḡ_e = J_e ω̄
                    g_bar_t[base:] = torch.bmm(extra_jac, omega_bar).squeeze(-1).T
                g_bar = g_bar_t.T
            elif extra_jac is not None:
                g_bar = torch.cat([grad_bar, torch.bmm(extra_jac, omega_bar).squeeze(-1)], dim=1)
            else:
                g_bar = grad_bar
            if extra_jac is not None:  # ∂L/∂J_e = g_e ⊗ ω̄
                jac_bar = g_extra.unsqueeze(-1) * omega_bar.transpose(1, 2)
            for layer in range(depth):
                if layer == 0 and swapped:  # ḡ_0 swapped: δᵀ ḡ_0 = swap⁻¹(δᵀ ḡ'), ḡ_0 Wᵀ = ḡ' swap(W)ᵀ
                    w_bar[0] = _swap_halves((g_bar_t @ deltas[0]).T, k, inverse=True)
                    delta_bar = g_bar @ _swap_halves(weights[0], k).T
                    del g_bar_t  # ḡ_0ᵀ is not needed past layer 0: freed when g_bar, its last view, is rebound
                else:
                    w_bar[layer] = deltas[layer].T @ g_bar
                    delta_bar = g_bar @ weights[layer].T
                g_bar = delta_bar * derivs[layer]
                if curvatures:
                    z_bar[layer] = delta_bar.mul_(curvatures[layer])
            # g_L = w_o (or E W_o): its adjoint ḡ_L lands on the output weights
            w_bar[depth] = g_bar.sum(0, keepdim=True) if basis is None else basis.T @ g_bar
        # the forward sweep's adjoint, from the output down
        a_bar = None
        b_out_bar = None
        if f_bar is not None:
            if basis is None:
                a_bar = f_bar[:, None] * weights[-1]
                w_out = f_bar[None] @ inputs[depth]
            else:  # h̄ (N, M)
                a_bar = f_bar @ weights[-1]
                w_out = f_bar.T @ inputs[depth]
            w_bar[depth] = w_out if w_bar[depth] is None else w_bar[depth].add_(w_out)
            b_out_bar = f_bar.sum(0, keepdim=True) if basis is None else f_bar.sum(0)
        b_bar: list[torch.Tensor | None] = [None] * depth
        for layer in reversed(range(depth)):
            zb = z_bar[layer]
            if a_bar is not None:
                zb = a_bar.mul_(derivs[layer]) if zb is None else zb.addcmul_(a_bar, derivs[layer])
            if zb is None:  # ReLU without f̄: ω does not depend on this layer's pre-activation
                b_bar[layer] = torch.zeros_like(biases[layer])
                continue
            b_bar[layer] = zb.sum(0) if biases[layer].dim() == 1 else zb.view(*biases[layer].shape[:1], -1,
                                                                                   zb.shape[1]).sum(1)
            # out of place: torch.utils.flop_counter does not count addmm_ (the copy is one (W, F) array)
            w_z = zb.T @ inputs[layer] if w_bar[layer] is None else torch.addmm(w_bar[layer], zb.T, inputs[layer])
            w_bar[layer] = w_z
            a_bar = zb @ weights[layer] if layer > 0 else None
            if layer == 0 and extra_jac is not None:  # ∂L/∂e through z_1 = [φ | e] W_1ᵀ + b_1
                extra_bar = zb @ weights[0][:, base:]
        grads = []
        for layer in range(depth):
            grads += [w_bar[layer], b_bar[layer]]
        grads += [w_bar[depth], b_out_bar]
        return (None, None, None, None, None, extra_bar, jac_bar, None, *grads)
