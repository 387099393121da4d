"""What every DeepCurrents LightningModule shares: Adam with the paper's step decay, NaN guard, and the
run's configuration stored in each checkpoint (so apps can rebuild any model kind from a checkpoint)."""

from __future__ import annotations

import math
from typing import Any

import lightning as L
import torch

from deepcurrents.errors import ConfigError, NonFiniteLossError

CHECKPOINT_KEY = "deepcurrents"


def network_kwargs(net: dict[str, Any], rff: dict[str, Any] | None = None) -> dict[str, Any]:
    """``model.net`` (the MLP: width, depth, activation, alpha_scale, ...) and ``model.rff`` (the random
    Fourier features: num_frequencies, sigma, enabled, seed) as the keyword arguments of ``NeuralCurrent``
    and ``FamilyCurrent``, checked: impossible sizes stop the run with one sentence naming the key."""
    rff = dict(rff or {})
    unknown = set(rff) - {"num_frequencies", "sigma", "enabled", "seed"}
    if unknown:
        raise ConfigError(f"model.rff has unknown keys {sorted(unknown)}; it takes num_frequencies, sigma, "
                          "enabled and seed.")
    kwargs = dict(net)
    kwargs.update(num_frequencies=rff.get("num_frequencies", 1024), sigma=rff.get("sigma", 2.0),
                  rff=bool(rff.get("enabled", True)), rff_seed=rff.get("seed"))
    for group, key in (("rff", "num_frequencies"), ("net", "width"), ("net", "depth")):
        value = kwargs.get(key, 1)
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise ConfigError(f"model.{group}.{key}={value!r} must be a positive integer.")
    if not float(kwargs["sigma"]) > 0:
        raise ConfigError(f"model.rff.sigma={kwargs['sigma']} must be positive.")
    if "alpha_scale" in kwargs and not float(kwargs["alpha_scale"]) > 0:
        raise ConfigError(f"model.net.alpha_scale={kwargs['alpha_scale']} must be positive.")
    return kwargs


class DeepCurrentsModule(L.LightningModule):
    """Base class. Subclasses define ``training_step`` (via ``compute_losses``) and ``final_evaluation``."""

    def __init__(self, optim: dict[str, Any]):
        super().__init__()
        lr, step_size, gamma = float(optim["lr"]), int(optim["step_size"]), float(optim["gamma"])
        if not lr > 0:
            raise ConfigError(f"model.optim.lr={lr} must be positive.")
        if step_size <= 0:
            raise ConfigError(f"model.optim.step_size={step_size} must be a positive number of steps.")
        if not 0 < gamma <= 1:
            raise ConfigError(f"model.optim.gamma={gamma} must be in (0, 1].")
        self.run_config: dict | None = None  # set by the entry point; saved in checkpoints

    def configure_optimizers(self):
        optim = self.hparams.optim
        opt = torch.optim.Adam(self.parameters(), lr=float(optim["lr"]))
        sched = torch.optim.lr_scheduler.StepLR(opt, step_size=int(optim["step_size"]), gamma=float(optim["gamma"]))
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}

    def check_finite(self, loss: torch.Tensor) -> None:
        if not math.isfinite(float(loss.detach())):
            raise NonFiniteLossError(
                f"The loss became {float(loss.detach())} at step {self.global_step}; training stopped. "
                "The last good checkpoint is kept (try a lower model.optim.lr)."
            )

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint[CHECKPOINT_KEY] = {
            "module": f"{type(self).__module__}.{type(self).__qualname__}",
            "config": self.run_config,
        }
