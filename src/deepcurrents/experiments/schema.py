"""One schema per config group: each setting's type, default, range and one-line meaning, checked once by
:func:`validate` before anything is built (``experiments.config.validate_config`` calls it).

The groups are stdlib dataclasses whose fields carry ``metadata={"check": ..., "help": ...}`` (:func:`setting`).
They are used only through this validator, not registered in Hydra's ConfigStore: structured configs would check
types in Hydra's words (not the sentences users and tests know) and not ranges, and the ``data`` and ``model``
nodes are keyword arguments of their ``_target_``, composed from experiments, presets and recipes.
Unknown keys are refused where a node's keys are fixed (``evaluation``, ``model.rff``, ``model.optim``, ...);
the top level of ``data``, ``model``, ``trainer`` and ``callbacks`` is left to their constructors.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import timedelta
from typing import Any

from omegaconf import DictConfig, OmegaConf

from deepcurrents.data.sampling import SAMPLING_KINDS
from deepcurrents.errors import ConfigError, number_at_least, number_between, positive_int, share
from deepcurrents.eval.meshing import CURVE_METHODS, MESH_METHOD_CHOICES
from deepcurrents.eval.meshing.curve_2d import check_curve_grid
from deepcurrents.models.base import GRID_ENCODING_KEYS, OPTIM_KEYS, RFF_KEYS
from deepcurrents.models.family_interpolation import INTERPOLATION_MIXES
from deepcurrents.models.schedules import SCHEDULES
from deepcurrents.nn.mlp import ACTIVATIONS

Check = Callable[[str, Any], Any]


def setting(default: Any, help: str, check: Check | None = None) -> Any:
    """A dataclass field: ``default`` (as conf/ sets it), ``help`` (what it is, its unit), ``check(key, value)``
    raising ConfigError in the user's sentence (None values are not checked: null means "not set")."""
    kwargs = {"default_factory": lambda: default} if isinstance(default, (list, dict)) else {"default": default}
    return field(metadata={"check": check, "help": help}, **kwargs)


def group(cls: type, help: str) -> Any:
    """A nested group (a dataclass of its own)."""
    return field(default_factory=cls, metadata={"group": cls, "help": help})


# ------------------------------------------------------------------------------------------------- checks

def max_time_seconds(value: Any) -> float | None:
    """``trainer.max_time`` in seconds: None (no time limit), a number of seconds, Lightning's "DD:HH:MM:SS"
    string, or a dict of timedelta keywords ({minutes: 3}). Anything else: one sentence naming the key."""
    if value is None:
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        seconds = float(value)
    elif isinstance(value, str):
        match = re.fullmatch(r"(\d+):(\d\d):(\d\d):(\d\d)", value.strip())
        if match is None:
            raise ConfigError(f"trainer.max_time={value!r} must be a number of seconds or DD:HH:MM:SS "
                              "(e.g. 00:00:03:00 for three minutes).")
        d, h, m, s = (int(g) for g in match.groups())
        seconds = timedelta(days=d, hours=h, minutes=m, seconds=s).total_seconds()
    elif isinstance(value, dict) or OmegaConf.is_dict(value):
        try:
            seconds = timedelta(**{k: float(v) for k, v in dict(value).items()}).total_seconds()
        except (TypeError, ValueError) as err:
            raise ConfigError(f"trainer.max_time={dict(value)!r} is not a duration ({err}).") from None
    else:
        raise ConfigError(f"trainer.max_time={value!r} must be a number of seconds or DD:HH:MM:SS.")
    if not seconds > 0:
        raise ConfigError(f"trainer.max_time={value!r} must be a positive duration.")
    return seconds


def integer(minimum: int = 1) -> Check:
    """An int ≥ minimum (errors.positive_int)."""
    return lambda key, value: positive_int(key, value, minimum)


def at_least(minimum: float = 0.0, strict: bool = False) -> Check:
    """A finite number ≥ minimum (> with strict; errors.number_at_least)."""
    return lambda key, value: number_at_least(key, value, minimum, strict)


def between(low: float, high: float) -> Check:
    """A number in [low, high] (errors.number_between)."""
    return lambda key, value: number_between(key, value, low, high)


def nonnegative(key: str, value: Any) -> None:
    """A non-negative number, in validate_config's sentence."""
    if not (isinstance(value, (int, float)) and value >= 0):
        raise ConfigError(f"{key}={value!r} must be a non-negative number.")


def nonnegative_between(low: float, high: float) -> Check:
    """nonnegative, then in [low, high] (evaluation.mesh.padding)."""
    def check(key: str, value: Any) -> None:
        nonnegative(key, value)
        number_between(key, value, low, high)
    return check


def boolean(key: str, value: Any) -> None:
    """true or false ('false', a string, is truthy)."""
    if value not in (True, False) or not isinstance(value, bool):
        raise ConfigError(f"{key}={value!r} must be true or false.")


def choice(options: tuple[str, ...]) -> Check:
    """One of ``options``."""
    def check(key: str, value: Any) -> None:
        if value not in options:
            raise ConfigError(f"{key}={value!r} must be one of {', '.join(options)}.")
    check.options = options  # type: ignore[attr-defined]  # for the reference (docs/settings.md)
    return check


def a_share(key: str, value: Any) -> None:
    """A share in (0, 1] (errors.share)."""
    share(key, value)


def budget_fraction(key: str, value: Any) -> None:
    """model.rff.coarse_to_fine: a fraction of the budget in [0, 1] (models.base.network_kwargs' words)."""
    value = number_at_least(key, value)
    if value > 1.0:
        raise ConfigError(f"{key}={value} must be a fraction of the budget in [0, 1] (0: every frequency from the "
                          "start).")


def frequency_fraction(key: str, value: Any) -> None:
    """model.rff.coarse_start: a fraction of the frequencies in (0, 1] (models.base.network_kwargs' words)."""
    value = number_at_least(key, value, strict=True)
    if value > 1.0:
        raise ConfigError(f"{key}={value} must be a fraction of the frequencies in (0, 1].")


def grid_levels(key: str, value: Any) -> None:
    """model.grid_encoding.levels: a non-negative integer (models.base.network_kwargs' words)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ConfigError(f"{key}={value!r} must be a non-negative integer (0: no grid).")


def warmup_fraction(key: str, value: Any) -> None:
    """model.optim.warmup in [0, 1) (models.schedules.check_schedule's words)."""
    if not 0.0 <= float(value) < 1.0:
        raise ConfigError(f"{key}={float(value)} must be a fraction of the budget in [0, 1).")


def unit_factor(key: str, value: Any) -> None:
    """model.optim.min_factor in [0, 1] (models.schedules.check_schedule's words)."""
    if not 0.0 <= float(value) <= 1.0:
        raise ConfigError(f"{key}={float(value)} must be in [0, 1].")


def adam_betas(key: str, value: Any) -> None:
    """model.optim.betas: two numbers in [0, 1) (models.schedules.check_schedule's words)."""
    if len(value) != 2 or not all(0.0 <= float(b) < 1.0 for b in value):
        raise ConfigError(f"{key}={list(value)} must be two numbers in [0, 1).")


def pool_size(key: str, value: Any) -> None:
    """data.sampling.pool: a non-negative integer (data.sampling.sampling_options' words)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ConfigError(f"{key}={value!r} must be a non-negative integer (0: fresh samples).")


def grid_dtype(key: str, value: Any) -> None:
    """model.grid.dtype: float32 or float64 (baselines.grid.GridModule's words)."""
    if str(value) not in ("float32", "float64"):
        raise ConfigError(f"{key}={str(value)!r} must be one of {sorted(('float32', 'float64'))}.")


def training_fraction(key: str, value: Any) -> None:
    """A fraction of the training budget in [0, 1) (nn.current.budget_fraction's words)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value < 1.0:
        raise ConfigError(f"{key}={value} must be a fraction of the training budget in [0, 1).")


def activation(key: str, value: Any) -> None:
    """model.net.activation: softplus or relu (nn.mlp's words)."""
    if value not in ACTIVATIONS:
        raise ConfigError(f"{key}='{value}' must be one of {', '.join(sorted(ACTIVATIONS))}.")


def harmonics(key: str, value: Any) -> None:
    """model.net.phase_harmonics: a whole number ≥ 0 (nn.current's words)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ConfigError(f"{key}={value!r} must be a whole number ≥ 0 (0: the paper's scalar network).")


def concentration(key: str, value: Any) -> None:
    """model.net.phase_sharpening: a concentration κ ≥ 0 (nn.current's words)."""
    kappa = float(value) if isinstance(value, (int, float)) else float("nan")
    if isinstance(value, bool) or not 0.0 <= kappa < float("inf"):
        raise ConfigError(f"{key}={value!r} must be a concentration κ ≥ 0 (0: off).")


def turns(key: str, value: Any) -> None:
    """model.net.f_turns: 0 or above 1 (nn.family's words)."""
    if 0 < number_at_least(key, value) <= 1:
        raise ConfigError(f"{key}={value} must be 0 (no window) or above 1: a surface's f spans one full jump, "
                          "which a window of at most one cannot hold.")


def relaxation(key: str, value: Any) -> None:
    """model.admm.relaxation in [1, 2) (baselines.grid's words)."""
    if not number_at_least(key, value, 1.0) < 2.0:
        raise ConfigError(f"{key}={value:g} must be in [1, 2).")


def positive_factor(key: str, value: Any) -> None:
    """model.grid_encoding.lr_factor > 0 (models.current_module's words)."""
    if not float(value) > 0:
        raise ConfigError(f"{key}={float(value)} must be positive.")


def interpolation_mix(key: str, value: Any) -> None:
    """model.interpolation_mix: shared or independent (models.autodecoder's words)."""
    if value not in INTERPOLATION_MIXES:
        raise ConfigError(f"{key}='{value}' must be one of {', '.join(INTERPOLATION_MIXES)}.")


def normalize(key: str, value: Any) -> None:
    """data.normalize: true, false or auto."""
    if value not in (True, False, "auto"):
        raise ConfigError(f"{key}={value!r} must be true, false or auto.")


def curve_scale(key: str, value: Any) -> None:
    """data.curve_scale: a positive number (data.ambient's words)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0 or not math.isfinite(value):
        raise ConfigError(f"{key}={value!r} must be a positive number (it multiplies the curve's coordinates).")


def dimension(key: str, value: Any) -> None:
    """data.dim: 2 or 3."""
    if value not in (2, 3):
        raise ConfigError(f"{key}={value} must be 2 or 3.")


def batch_kind(key: str, value: Any) -> None:
    """data.batch_kind: current or closest_point (data.recon's words)."""
    if value not in ("current", "closest_point"):
        raise ConfigError(f"{key}='{value}' must be 'current' or 'closest_point'.")


def importance_share(key: str, value: Any) -> None:
    """data.sampling.uniform_fraction of a minimal surface in (0, 1] (data.sampling's words)."""
    share(key, value, "a uniform share bounds the importance weights")


def torch_threads(key: str, value: Any) -> None:
    """torch_threads: a positive integer or auto."""
    if value != "auto" and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
        raise ConfigError(f"torch_threads={value!r} must be a positive integer, auto (the cores left beside the "
                          "loader workers) or null (torch's choice).")


def max_steps(key: str, value: Any) -> None:
    """trainer.max_steps: a positive integer, or -1 (Lightning's "no step limit")."""
    if value != -1:
        positive_int(key, value)


def max_time(key: str, value: Any) -> None:
    """trainer.max_time: a duration (max_time_seconds)."""
    max_time_seconds(value)


def curve_grid(key: str, value: Any) -> None:
    """evaluation.curve.resolution: an integer ≥ 8 that the 2D mesher can take."""
    positive_int(key, value, 8)
    check_curve_grid(value, key)




# ------------------------------------------------------------------------------------------------- groups

@dataclass
class Trainer:
    """``trainer``: keyword arguments of lightning.Trainer (conf/trainer/); other Trainer keys pass unchecked."""
    accelerator: str = setting("auto", "cpu, gpu or auto (Lightning's choice)")
    devices: int = setting(1, "processes (GPUs or CPU ranks) per machine")
    num_nodes: int = setting(1, "machines of a DDP run")
    strategy: str | None = setting(None, "ddp for several devices (trainer=ddp, ddp_cpu)")
    max_steps: int = setting(100000, "training steps; -1: no step limit (then max_time is needed)", max_steps)
    max_time: Any = setting(None, "wall-clock budget of the fit loop: seconds or DD:HH:MM:SS", max_time)
    max_epochs: int = setting(-1, "Lightning's epoch limit (-1: none; the loaders are endless)")
    log_every_n_steps: int = setting(50, "steps between training logs", integer())
    num_sanity_val_steps: int = setting(0, "Lightning's sanity validation steps (no validation here)")
    limit_val_batches: int = setting(0, "Lightning's validation batches (no validation here)")
    precision: str = setting("32-true", "arithmetic precision; only 32-true (float32) is supported")
    enable_progress_bar: bool = setting(True, "Lightning's progress bar")
    enable_model_summary: bool = setting(True, "Lightning's model summary at the start")
    gradient_clip_val: float | None = setting(None, "clip the gradient norm to this (null: no clipping)")
    deterministic: bool = setting(False, "torch's deterministic algorithms")


@dataclass
class ModelCheckpoint:
    """``callbacks.model_checkpoint``: keyword arguments of Lightning's ModelCheckpoint."""
    filename: str = setting("step{step:07d}", "checkpoint file name pattern")
    auto_insert_metric_name: bool = setting(False, "Lightning's metric names in the file name")
    save_last: bool = setting(True, "keep last.ckpt (the one a resume reads)")
    save_top_k: int = setting(0, "best checkpoints kept by a monitored metric (0: none)")
    every_n_train_steps: int = setting(1000, "steps between checkpoints", integer())


@dataclass
class Media:
    """``callbacks.media``: renders of the current during and after training (models.callbacks.MediaCallback)."""
    every_n_steps: int = setting(10000, "steps between renders (0: none during training)")
    final: bool = setting(True, "a render after training")
    size: int = setting(128, "image side, pixels")
    samples: int = setting(32, "ω evaluations per ray")
    grid: int = setting(32, "resolution of the proposal grid")
    azimuth: float = setting(35.0, "camera azimuth, degrees")
    elevation: float = setting(25.0, "camera elevation, degrees")


@dataclass
class Callbacks:
    """``callbacks``: Lightning callbacks by name (null: off)."""
    model_checkpoint: ModelCheckpoint | None = group(ModelCheckpoint, "periodic checkpoints")
    lr_monitor: Any = setting(None, "Lightning's LearningRateMonitor node (null: off)")
    media: Media | None = group(Media, "renders")


@dataclass
class Sharpened:
    """``evaluation.sharpened``: the area bound of the current concentrated onto its meshed phase level."""
    kappa: float = setting(16.0, "von Mises concentration κ", nonnegative)
    samples: int = setting(131072, "samples of the bound (0: skip it)", integer(0))


@dataclass
class Polish:
    """``evaluation.mesh.polish``: minimal surfaces' mesh flow after the extraction (eval.meshing.polish)."""
    enabled: bool = setting(True, "polish the final mesh (mesh_polished.ply, mesh_area_polished, _extrapolated)",
                            boolean)
    edge_length: float = setting(0.025, "level 1's edge length, a share of Γ's largest extent", between(1e-4, 0.5))
    levels: int = setting(3, "meshes of edges h, h/2, …: two or more give the Richardson extrapolation", integer())
    tolerance: float = setting(1.0e-6, "a level ends when its area changes by less than this share a step",
                               at_least(strict=True))
    max_iterations: int = setting(100, "most steps of the flow per level", integer())
    remesh_iterations: int = setting(10, "iterations of the isotropic remesher before level 1", integer())


@dataclass
class MeshEvaluation:
    """``evaluation.mesh``: the final 3D mesh (eval.meshing)."""
    method: str = setting("auto", "phase, level_set or auto (phase for minimal surfaces, level_set otherwise)",
                          choice(tuple(MESH_METHOD_CHOICES)))
    resolution: int = setting(128, "cells along the longest side of the meshed region", integer(8))
    delta: float = setting(5.0e-3, "keep faces with |ω| ≥ delta", nonnegative)
    boundary_tube: float = setting(0.04, "radius of the tube around Γ that is cut and closed, model units",
                                   nonnegative)
    padding: float = setting(0.15, "the meshed box grown by this fraction of its size", nonnegative_between(0, 1))
    newton_steps: int = setting(3, "Newton steps that move vertices onto the level", integer(0))
    min_component: float = setting(0.01, "drop components below this fraction of the area", between(0, 1))
    min_alignment: float = setting(0.5, "level_set: keep faces where cos(ω, ∇f) ≥ this", between(-1, 1))
    close_boundary: bool = setting(True, "cut the tube and close the border onto Γ (false: the |ω| ≥ δ cut only)",
                                   boolean)
    strip_rows: int | None = setting(None, "rows of the strip from the cut border to Γ (null: automatic)",
                                     integer())
    level_blend: float = setting(0.0, "level_set: distance to Γ within which the level follows f along Γ",
                                 nonnegative)
    weak_share: float = setting(0.0, "drop regions reaching Γ's tube whose |ω| is under this share of the median "
                                "face's (caps across openings; 0: off)", between(0, 1))
    polish: Polish = group(Polish, "the minimal surface's mesh flow")


@dataclass
class CurveEvaluation:
    """``evaluation.curve``: the final 2D curve (eval.meshing.curve_2d)."""
    resolution: int = setting(256, "cells along the longest side of the grid", curve_grid)
    delta: float = setting(5.0e-3, "keep segments with |ω| ≥ delta", nonnegative)
    boundary_tube: float = setting(0.03, "radius of the disc around each boundary point that is cut, model units",
                                   nonnegative)
    min_alignment: float = setting(0.5, "level_set: keep segments where cos(ω, ∇f) ≥ this", between(-1, 1))
    method: str = setting("phase", "phase or level_set (the paper's f = s)", choice(tuple(CURVE_METHODS)))


@dataclass
class Evaluation:
    """``evaluation``: the final evaluation of every kind of run (conf/train.yaml)."""
    mass_samples: int = setting(1048576, "most uniform samples of the extraction-free mass bound", integer())
    mass_rel_stderr: float | None = setting(0.0075, "stop the mass bound at this relative standard error "
                                            "(null: always mass_samples)", nonnegative)
    mass_refine: int = setting(3, "cells near Γ split into mass_refine^d sub-cells (1: off)", integer())
    mass_refine_mesh: bool = setting(False, "refine the cells the final mesh crosses too", boolean)
    mass_tube_radius: float = setting(0.02, "3D: points this close to Γ are integrated apart, model units (0: off)",
                                      nonnegative)
    sharpened: Sharpened = group(Sharpened, "the sharpened area bound")
    ucd_samples: int = setting(100000, "uniform samples of a reconstruction target for UCD", integer())
    seed: int = setting(12345, "seed of the evaluation's samples", integer(0))
    max_shapes: int | None = setting(None, "families: evaluate only the first N training shapes (null: all)",
                                     integer())
    mesh: MeshEvaluation = group(MeshEvaluation, "the 3D mesh")
    curve: CurveEvaluation = group(CurveEvaluation, "the 2D curve")


@dataclass
class Rff:
    """``model.rff``: random Fourier features [sin 2πBx, cos 2πBx], B ~ N(0, σ²) (paper §4.3)."""
    num_frequencies: int = setting(1024, "rows of B (twice as many features)", integer())
    sigma: float = setting(2.0, "σ of B", at_least(strict=True))
    enabled: bool = setting(True, "false: x goes straight into the MLP (ablation=no_rff)")
    seed: int | None = setting("${seed}", "seed of B")
    coarse_to_fine: float = setting(0.0, "frequencies open in order of |B| over this fraction of the budget (0: all "
                                    "at once)", budget_fraction)
    coarse_start: float = setting(0.25, "share of the frequencies open from the first step", frequency_fraction)


@dataclass
class GridEncoding:
    """``model.grid_encoding``: learned multiresolution grid features beside the Fourier features (nn.MultiresGrid)."""
    levels: int = setting(0, "grids from base to finest resolution (0: off)", grid_levels)
    base_resolution: int = setting(4, "cells along a side of the coarsest grid")
    finest_resolution: int = setting(64, "cells along a side of the finest grid")
    features: int = setting(2, "features per grid vertex and level")
    table_size: int = setting(262144, "rows a level with more vertices is hashed into")
    init_scale: float = setting(1.0e-4, "initial values uniform in ±init_scale")
    lr_factor: float = setting(1.0, "the table's learning rate as a multiple of model.optim.lr", positive_factor)


@dataclass
class Net:
    """``model.net``: the MLP on the features and ω's normalisation (keyword arguments of nn.NeuralCurrent)."""
    width: int = setting(256, "hidden units per layer", integer())
    depth: int = setting(4, "hidden layers", integer())
    activation: str = setting("softplus", "softplus (paper) or relu (ablation=relu)", activation)
    alpha_scale: float = setting(1.0e-3, "the scale a of ω = ∇f + a·α", at_least(strict=True))
    zero_init_output: bool = setting(True, "f starts constant (ω = α)")
    matmul_precision: str = setting("highest", "highest: IEEE float32 products; medium: bf16 or TF32 inside them")
    phase_harmonics: int = setting(0, "K > 0 (3D): harmonics of the phase in f", harmonics)
    phase_harmonics_start: float = setting(0.0, "fraction of the budget before the harmonics open",
                                           training_fraction)
    phase_sharpening: float = setting(0.0, "κ > 0: ω = ψ'(φ)·(∇f + a·α), κ's growth rate", concentration)
    phase_sharpening_start: float = setting(0.0, "fraction of the budget before κ starts to grow",
                                            training_fraction)
    f_turns: float = setting(0.0, "families: f = W·tanh(h), a window of f_turns full jumps (0: off)", turns)


@dataclass
class Optim:
    """``model.optim``: Adam and its schedule (models.base.DeepCurrentsModule, models.schedules)."""
    lr: float = setting(5.0e-4, "Adam's learning rate", at_least(strict=True))
    step_size: float = setting(10000, "step schedule: lr × gamma every step_size steps", at_least(1.0))
    gamma: float = setting(0.6, "step schedule: the factor of each decay", a_share)
    schedule: str = setting("step", "step (paper) or cosine (warm-up then cosine over the budget)",
                            choice(tuple(SCHEDULES)))
    warmup: float = setting(0.0, "cosine: linear warm-up over this fraction of the budget", warmup_fraction)
    min_factor: float = setting(0.0, "cosine: the rate ends at min_factor × lr", unit_factor)
    fused: bool = setting(False, "PyTorch's fused Adam kernel", boolean)
    betas: list | None = setting(None, "Adam's betas (null: PyTorch's)", adam_betas)
    check_every: int | None = setting(None, "steps between reads of the loss's finiteness (null: 1 on a CPU, 32 on "
                                      "a GPU, where a read each step stalls the device)", integer())


@dataclass
class LatentFit:
    """``model.latent_fit``: held-out shapes fitted by Adam on their latent code alone."""
    steps: int = setting(300, "Adam steps per held-out shape", integer())
    lr: float = setting(1.0e-2, "the codes' learning rate", at_least(strict=True))
    num_samples: int = setting(2000, "ambient samples per step", integer())
    num_surface_samples: int = setting(2000, "surface samples per step", integer())
    prior_weight: float = setting(0.0, "weight of the Gaussian prior on the code (0: off)", at_least())


@dataclass
class InterpolationSampling:
    """``model.interpolation_sampling``: the points of the interpolation regulariser."""
    kind: str = setting("uniform", "uniform in U, or near: around the pair's surface samples")
    near_sigma: float = setting(0.03, "near: σ of the Gaussians, model units")
    uniform_fraction: float = setting(0.5, "near: the share drawn uniformly")


@dataclass
class Grid:
    """``model.grid``: the grid baseline's voxels (baselines.grid)."""
    resolution: int | None = setting(None, "N cells a side (null: matched to the network's parameters)",
                                     integer(4))
    dtype: str = setting("float64", "float32 or float64", grid_dtype)


@dataclass
class Admm:
    """``model.admm``: the grid baseline's solver."""
    rho: float = setting(0.5, "initial penalty ρ = rho·h/alpha_scale", at_least(strict=True))
    relaxation: float = setting(1.6, "over-relaxation (1: plain ADMM)", relaxation)
    balance: float = setting(10.0, "rebalance ρ when one residual is this × the other (0: fixed ρ)", at_least())
    tol: float = setting(1.0e-3, "stop when both relative residuals are below tol", at_least(strict=True))
    min_iterations: int = setting(10, "iterations before the stopping test", integer(0))


@dataclass
class Sampling:
    """``data.sampling``: how U is sampled for the loss (data.sampling, data.recon.ambient_options); each data kind
    takes its own keys (its constructor names the others)."""
    kind: str = setting("uniform", "uniform, sobol or importance (minimal surfaces); uniform or near (targets)")
    uniform_fraction: float = setting(0.5, "importance or near: the share drawn uniformly")
    pool: int = setting(0, "> 0: batches drawn from this many samples with α precomputed", pool_size)
    resolution: int = setting(16, "importance: cells along a side of the score grid")
    power: float = setting(1.0, "importance: the exponent of the cell scores")
    near_sigma: float = setting(0.02, "near: σ of the Gaussians, model units")
    anchors: int = setting(4096, "near: fixed points of the target the Gaussians sit on")
    weighted: bool = setting(True, "near: importance weights 1/q")


@dataclass
class MinimalSampling(Sampling):
    """``data.sampling`` of a minimal surface (data.sampling.AmbientSampler): uniform, sobol or importance."""
    kind: str = setting("uniform", "uniform (paper), sobol (scrambled quasi-random) or importance (cells near Γ)",
                        choice(tuple(SAMPLING_KINDS)))
    uniform_fraction: float = setting(0.5, "importance: the share of each batch drawn uniformly", importance_share)
    resolution: int = setting(16, "importance: cells along a side of the score grid", integer())
    power: float = setting(1.0, "importance: the exponent of the cell scores", at_least())


# ---------------------------------------------------------------------------------------- data kinds

@dataclass
class MinimalSurfaceData:
    """``data`` of a minimal surface (data.MinimalSurfaceDataModule): Γ and the samples of U."""
    dim: int = setting(3, "2 (points of a plane) or 3 (curves in space)", dimension)
    curve: str | None = setting("trefoil", "3D: a named curve or a curve file")
    curve_vertices: int = setting(100, "vertices per loop of a named curve", integer(3))
    curve_scale: float = setting(1.0, "multiplies the curve's coordinates", curve_scale)
    normalize: Any = setting("auto", "true, false or auto: centre and scale the curve into [-0.5, 0.5]^3", normalize)
    max_vertices_per_loop: int | None = setting(512, "denser loops are resampled by arc length (null: keep all)",
                                                integer(3))
    points: list | None = setting(None, "2D: the boundary points [[x, y], ...]")
    signs: list | None = setting(None, "2D: the orientation ±1 of each point")
    num_samples: int = setting(4096, "samples of U per step", integer())
    num_workers: int = setting(0, "loader workers", integer(0))
    seed: int = setting("${seed}", "seed of the samples")
    sampling: MinimalSampling = group(MinimalSampling, "how U is sampled")


@dataclass
class FamilyData:
    """``data`` of a family (data.family.FamilyDataModule): meshes with boundaries, augmented, per batch."""
    path: str = setting("${paths.data_dir}/anny/hands", "the folder of meshes")
    max_meshes: int | None = setting(None, "only the first N meshes by file name (null: all)")
    held_out: int = setting(0, "the last N meshes are not trained (the final evaluation fits their codes)")
    meshes_per_batch: int = setting(8, "meshes per step and DDP rank")
    num_samples: int = setting(4000, "ambient samples per mesh", integer())
    num_surface_samples: int = setting(4000, "surface-loss samples per mesh")
    augment: bool = setting(True, "random rotations, scales and shifts of each mesh")
    rotation_deg: float = setting(10.0, "each Euler angle ~ U[-r, r], degrees", at_least())
    scale_range: list = setting([0.85, 1.15], "each loop's two principal scales ~ U[low, high]")
    shift: float = setting(0.05, "translation ~ U[-s, s]^3, model units", at_least())
    bound: float = setting(0.98, "the augmented mesh stays inside [-bound, bound]^3", at_least(strict=True))
    mesh_scale_range: list = setting([1.0, 1.0], "the whole mesh × a log-uniform factor in [low, high]")
    boundary_sigma: float = setting(0.1, "σ of the boundary weighting, model units", at_least(strict=True))
    boundary_weighting: bool = setting(True, "the metric's weighting near Γ (ablation=no_boundary_weighting)")
    metric_band: float | None = setting(None, "samples farther than this from Σ get the Euclidean metric")
    surface_epsilon: Any = setting(0.02, "ε of the surface loss's offsets y ± εn, model units")
    sampling: Sampling = group(Sampling, "the ambient samples")
    num_workers: int = setting(6, "loader workers (augmentation and sampling)", integer(0))
    seed: int = setting("${seed}", "seed of the samples and augmentations")


@dataclass
class CurveMetricData:
    """``data`` of a 2D reconstruction (data.recon.CurveMetricDataModule): a curve Σ and the metric it induces."""
    curve: Any = setting("semicircle", "semicircle or a list of [x, y] points")
    radius: float = setting(0.5, "the semicircle's radius")
    num_samples: int = setting(4096, "samples of U per step", integer())
    num_workers: int = setting(0, "loader workers")
    seed: int = setting("${seed}", "seed of the samples")
    sampling: Sampling = group(Sampling, "how U is sampled")


@dataclass
class ReconstructionData:
    """``data`` of a reconstruction (data.recon.ReconstructionDataModule): a target surface Σ and its boundary Γ."""
    mesh: str | None = setting(None, "a mesh file as the target")
    points: str | None = setting(None, "an oriented point cloud as the target")
    curve: str | None = setting(None, "the boundary Γ of a point cloud (a curve file)")
    category: str | None = setting(None, "a part of the generated dataset (hands, heads, ...)")
    source: str = setting("anny", "anny or faust: the dataset of category")
    index: int = setting(0, "which part of the category")
    root: str = setting("${paths.data_dir}", "the dataset folder")
    normalize: Any = setting("auto", "true: centre and scale into [-0.5, 0.5]^3; auto: only if it does not fit",
                             normalize)
    num_samples: int = setting(4000, "ambient samples per step", integer())
    num_surface_samples: int = setting(4000, "samples on the target per step")
    boundary_sigma: float = setting(0.1, "σ of the boundary weighting, model units", at_least(strict=True))
    boundary_weighting: bool = setting(True, "the metric's weighting near Γ")
    surface_loss: bool = setting(True, "the surface loss (ablation=no_surface_loss)")
    curve_tolerance: float = setting(0.05, "Γ within this fraction of the cloud's size of its points",
                                     at_least(strict=True))
    batch_kind: str = setting("current", "current, or closest_point (the closest-point baseline's batches)",
                              batch_kind)
    near_sigma: float = setting(0.05, "closest_point batches: σ of the points around Σ, model units",
                                at_least(strict=True))
    num_workers: int = setting(1, "loader workers (closest-point queries)", integer(0))
    seed: int = setting("${seed}", "seed of the samples")
    sampling: Sampling = group(Sampling, "the ambient samples")


DATA_KINDS: dict[str, type] = {
    "deepcurrents.data.MinimalSurfaceDataModule": MinimalSurfaceData,
    "deepcurrents.data.minimal.MinimalSurfaceDataModule": MinimalSurfaceData,
    "deepcurrents.data.family.FamilyDataModule": FamilyData,
    "deepcurrents.data.recon.CurveMetricDataModule": CurveMetricData,
    "deepcurrents.data.recon.ReconstructionDataModule": ReconstructionData,
}


# --------------------------------------------------------------------------------------- model kinds

@dataclass
class CurrentModel:
    """``model`` of a minimal surface (models.CurrentModule): the neural current of paper §4."""
    rff: Rff = group(Rff, "random Fourier features")
    grid_encoding: GridEncoding = group(GridEncoding, "learned grid features")
    net: Net = group(Net, "the MLP")
    optim: Optim = group(Optim, "Adam and its schedule")
    evaluation: Any = setting("${evaluation}", "the root evaluation node")
    surface_weight: float = setting(1.0, "weight of the surface loss")
    surface_margin: float = setting(0.01, "δ of the surface hinge loss, model units")
    mass_weight: float = setting(0.0, "> 0: + λ E|ω| at the ambient samples")
    level_weight: float = setting(0.0, "> 0: + λ L_level (f's drop straddles the mesher's level)")
    latent_dim: int = setting(256, "families: size of a shape's latent code")
    boundary_dim: int = setting(256, "families: size of the boundary's code")
    latent_lr_factor: float = setting(1.0, "families: the codes' learning rate as a multiple of optim.lr")
    latent_fit: LatentFit = group(LatentFit, "families: held-out shapes")


@dataclass
class ReconstructionModel(CurrentModel):
    """``model`` of a reconstruction (models.reconstruction.ReconstructionModule): current and surface losses."""
    surface_weight: float = setting(1.0, "weight of the surface loss", at_least())
    surface_margin: float = setting(0.01, "δ of the surface hinge loss, model units", at_least(strict=True))
    mass_weight: float = setting(0.0, "> 0: + λ E|ω| at the ambient samples", at_least())
    level_weight: float = setting(0.0, "> 0: + λ L_level (f's drop straddles the mesher's level)", at_least())


@dataclass
class AutodecoderModel(CurrentModel):
    """``model`` of a family (models.autodecoder.AutodecoderModule): one current per latent code."""
    surface_weight: float = setting(1.0, "weight of the surface loss", at_least())
    mass_weight: float = setting(0.0, "> 0: + λ E|ω| on the training shapes' samples", at_least())
    level_weight: float = setting(0.0, "> 0: + λ L_level (f's drop straddles the mesher's level)", at_least())
    latent_lr_factor: float = setting(1.0, "the codes' learning rate as a multiple of optim.lr",
                                      at_least(strict=True))
    latent_std: float = setting(0.1, "σ of the codes' initialisation", at_least())
    winding_weight: float = setting(0.0, "> 0: weight of the cap on f's drop across Σ", at_least())
    winding_reach: float = setting(1.0, "the cap's offsets as a multiple r ≥ 1 of the surface loss's ε",
                                   at_least(1.0))
    interpolation_weight: float = setting(0.0, "> 0: mass loss of random interpolants of the batch's codes",
                                          at_least())
    interpolation_mix: str = setting("shared", "shared: one t for code and boundary; independent: apart",
                                     interpolation_mix)
    interpolation_sampling: InterpolationSampling = group(InterpolationSampling, "the regulariser's points")


@dataclass
class GridModel(CurrentModel):
    """``model`` of the grid baseline (baselines.grid.GridModule): ADMM on a voxel grid."""
    grid: Grid = group(Grid, "the voxels")
    admm: Admm = group(Admm, "the solver")


@dataclass
class ClosestPointModel(CurrentModel):
    """``model`` of the closest-point baseline (baselines.closest_point.ClosestPointModule)."""
    near_fraction: Any = setting(None, "retired (never read): refused if set")
    near_sigma: Any = setting(None, "retired: the near points' noise is data.near_sigma")
    time_budget_s: float | None = setting(None, "seconds of training", at_least(strict=True))
    wall_time_from: str | None = setting(None, "a DeepCurrents run's metrics.json: train for its train_seconds")


MODEL_KINDS: dict[str, type] = {
    "deepcurrents.models.CurrentModule": CurrentModel,
    "deepcurrents.models.current.CurrentModule": CurrentModel,
    "deepcurrents.models.reconstruction.ReconstructionModule": ReconstructionModel,
    "deepcurrents.models.autodecoder.AutodecoderModule": AutodecoderModel,
    "deepcurrents.baselines.grid.GridModule": GridModel,
    "deepcurrents.baselines.closest_point.ClosestPointModule": ClosestPointModel,
}


@dataclass
class Root:
    """The root keys of conf/train.yaml."""
    task_name: str = setting("minimal", "the run's name (its output folder)")
    seed: int = setting(0, "the run's seed", integer(0))
    ckpt_path: str | None = setting(None, "resume from this checkpoint")
    init_from: str | None = setting(None, "warm start: the network of this checkpoint (not its step or Γ)")
    torch_threads: Any = setting(None, "torch threads: an integer, auto or null (torch's choice)", torch_threads)
    objective: str | None = setting(None, "a metrics.json key returned to Hydra sweepers")
    suite: Any = setting(None, "several runs and a report (set by experiments)")


# the groups whose node's keys are fixed: an unknown key is refused (each in its constructor's words)
UNKNOWN_KEY_WORDS: dict[str, Callable[[str, list[str], list[str]], str]] = {
    "model.rff": lambda path, unknown, known:
        f"model.rff has unknown keys {sorted(unknown)}; it takes {', '.join(sorted(RFF_KEYS))}.",
    "model.grid_encoding": lambda path, unknown, known:
        f"model.grid_encoding has unknown keys {sorted(unknown)}; it takes {', '.join(sorted(GRID_ENCODING_KEYS))}.",
    "model.optim": lambda path, unknown, known:
        f"model.optim.{sorted(unknown)[0]} is not a setting of model.optim (its settings: {', '.join(OPTIM_KEYS)}).",
}
FIXED_KEYS = ("evaluation", "model.rff", "model.grid_encoding", "model.optim", "model.grid", "model.admm")


def _unknown_key_sentence(path: str, unknown: list[str], known: list[str]) -> str:
    words = UNKNOWN_KEY_WORDS.get(path)
    if words is not None:
        return words(path, unknown, known)
    return f"{path}.{unknown[0]} is not a setting of {path} (its settings: {', '.join(known)})."


def settings(cls: type) -> Iterator[dataclasses.Field]:
    """The fields of a group's dataclass, in order."""
    return iter(dataclasses.fields(cls))


def check_node(node: Any, cls: type, path: str) -> None:
    """``node`` (a DictConfig) against the group ``cls``: unknown keys where its keys are fixed, then each value."""
    if not OmegaConf.is_dict(node):
        return
    fields = {f.name: f for f in settings(cls)}
    if path in FIXED_KEYS or path.startswith("evaluation."):
        unknown = [str(k) for k in node if k not in fields and not str(k).startswith("_")]
        if unknown:
            raise ConfigError(_unknown_key_sentence(path, unknown, list(fields)))
    for name, f in fields.items():
        if name not in node:
            continue
        value = node[name]
        key = f"{path}.{name}" if path else name
        if "group" in f.metadata:
            check_node(value, f.metadata["group"], key)
        elif value is not None and f.metadata.get("check") is not None:
            f.metadata["check"](key, value)


def validate(cfg: DictConfig) -> None:
    """Raises ConfigError naming the first impossible value of the composed config: each group against its schema,
    then the rules between settings."""
    check_node(cfg.get("evaluation"), Evaluation, "evaluation")
    check_node(cfg.get("trainer"), Trainer, "trainer")
    check_node(cfg, Root, "")
    check_node(cfg.get("callbacks"), Callbacks, "callbacks")
    for group_name, kinds in (("data", DATA_KINDS), ("model", MODEL_KINDS)):
        node = cfg.get(group_name)
        if OmegaConf.is_dict(node) and str(node.get("_target_")) in kinds:
            check_node(node, kinds[str(node.get("_target_"))], group_name)
    check_rules(cfg)


def check_rules(cfg: DictConfig) -> None:
    """The rules between settings (each names the settings it joins)."""
    seconds = max_time_seconds(OmegaConf.select(cfg, "trainer.max_time"))
    if OmegaConf.select(cfg, "trainer.max_steps") == -1 and seconds is None:
        raise ConfigError("trainer.max_steps=-1 (no step limit) needs a time budget: set trainer.max_time "
                          "(seconds or DD:HH:MM:SS).")
    precision = OmegaConf.select(cfg, "trainer.precision")
    if precision is not None and str(precision) not in ("32-true", "32"):
        value = str(precision)
        if value in ("64-true", "64"):
            why = "the final evaluation, meshing and rendering build float32 points and grids"
        elif "16" in value:  # 16-mixed, bf16-mixed, 16-true, bf16-true, 16, bf16
            # under autocast α's products would meet float32 operands (a dtype error deep in torch)
            why = ("its training pass and Biot–Savart run in the parameters' precision whatever autocast asks (the "
                   "mass loss is sensitive to rounding), so half precision cannot speed it up; for faster matrix "
                   "products use model.net.matmul_precision=medium (bf16 or TF32 internals in float32 products)")
        else:
            why = "32-true is the only precision it runs in"
        raise ConfigError(f"trainer.precision={precision} is not supported: DeepCurrents trains in float32 "
                          f"(32-true), and {why}.")
    clip = OmegaConf.select(cfg, "trainer.gradient_clip_val")
    if clip and str(OmegaConf.select(cfg, "model._target_", default="")).endswith(".GridModule"):
        # else Lightning's "remove Trainer(gradient_clip_val=0.1)", a setting the user never typed
        raise ConfigError(f"trainer.gradient_clip_val={clip} (set by recipe=sharp, or on the command line) does "
                          "not apply to the grid method (model=grid): its ADMM takes no gradient steps; drop "
                          "recipe=sharp, or set trainer.gradient_clip_val=null.")
    harmonics_k = OmegaConf.select(cfg, "model.net.phase_harmonics")
    two_d = OmegaConf.select(cfg, "data.dim") == 2 or str(OmegaConf.select(cfg, "data._target_")).endswith(
        ".CurveMetricDataModule")
    if harmonics_k and two_d and str(OmegaConf.select(cfg, "model._target_")).endswith(("CurrentModule",
                                                                                        "ReconstructionModule")):
        raise ConfigError(f"model.net.phase_harmonics={harmonics_k} needs a 3D boundary (the harmonics are "
                          "those of the solid angle); use 0 for 2D curves.")
    if (OmegaConf.select(cfg, "model.mass_weight") or 0) > 0 and OmegaConf.select(cfg, "data.sampling.kind") == "near":
        # the near samples' importance weights are folded into the metric, so E|ω| would not be the mass
        raise ConfigError("model.mass_weight needs uniform ambient samples; data.sampling.kind=near weights "
                          "them into the metric only.")


# ------------------------------------------------------------------------------------------- reference

def _range(f: dataclasses.Field) -> str:
    """The check of a field in words, from its docstring (the first sentence) or its choices."""
    check = f.metadata.get("check")
    if check is None:
        return ""
    options = getattr(check, "options", None)
    if options is not None:
        return " | ".join(options)
    doc = (check.__doc__ or "").strip().split("\n")[0]
    closure = getattr(check, "__closure__", None) or ()
    args = [c.cell_contents for c in closure if isinstance(c.cell_contents, (int, float, bool))]
    name = getattr(check, "__qualname__", "").split(".")[0]
    words = {"integer": lambda a: f"integer ≥ {a[0]}", "at_least": lambda a: f"{'>' if a[-1] else '≥'} {a[0]:g}",
             "between": lambda a: f"[{a[0]:g}, {a[1]:g}]", "nonnegative_between": lambda a: f"[{a[0]:g}, {a[1]:g}]"}
    if name in words and args:
        return words[name](args)
    words_of = doc.split(":", 1)[-1].strip() if ":" in doc else doc
    return re.sub(r" \([^()]*\)\.?$", "", words_of).rstrip(".")  # the doc's pointer to where the words come from


def _rows(cls: type, path: str) -> Iterator[tuple[str, str, str, str, str]]:
    for f in settings(cls):
        key = f"{path}.{f.name}" if path else f.name
        if "group" in f.metadata:
            yield from _rows(f.metadata["group"], key)
            continue
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        text = "null" if default is None else str(default).lower() if isinstance(default, bool) else str(default)
        yield key, str(f.type).replace(" | ", " or "), text, _range(f), f.metadata["help"]


def reference() -> str:
    """docs/settings.md: every setting of every group (key, type, default, range, meaning), from this schema."""
    out = ["# Settings", "", "Generated from `src/deepcurrents/experiments/schema.py` by "
           "`python -m deepcurrents.experiments.schema > docs/settings.md`; do not edit by hand. Defaults are those "
           "of conf/ before presets and recipes.", ""]
    groups = [("root", Root, ""), ("trainer", Trainer, "trainer"), ("callbacks", Callbacks, "callbacks"),
              ("evaluation", Evaluation, "evaluation")]
    groups += [(f"data: `{t}`", c, "data") for t, c in DATA_KINDS.items() if "minimal." not in t]
    groups += [(f"model: `{t}`", c, "model") for t, c in MODEL_KINDS.items() if "current." not in t]
    for title, cls, path in groups:
        out += [f"## {title}", "", (cls.__doc__ or "").strip(), "", "| key | type | default | range | meaning |",
                "|---|---|---|---|---|"]
        out += ["| " + " | ".join(cell.replace("|", "\\|") for cell in (f"`{k}`", t, f"`{d}`", r, h)) + " |"
                for k, t, d, r, h in _rows(cls, path)]
        out.append("")
    return "\n".join(out)


if __name__ == "__main__":
    print(reference(), end="")
