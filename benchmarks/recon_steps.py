"""Reconstruction quality per step: one run through the package's own code (Hydra config, DataModule,
LightningModule, Lightning), with the UCD of the mesh measured at given steps (on the weights and on an EMA
of them) and the CPU seconds of the training steps (the batches made in this process, evaluation excluded).
Quality per step does not depend on the machine's load, so variants compare at equal steps on a shared
machine; their per-step cost is the ``s_per_step`` column (process CPU time, one thread).

    python benchmarks/recon_steps.py NAME --steps 1000 --evals 250,500 [--ema 0.99] -- OVERRIDE ...
    python benchmarks/recon_steps.py ref --steps 1000 -- experiment=recon_head preset=paper

Defaults: experiment=recon_hand preset=cpu (overrides come after them). Prints one JSON line per evaluation
and writes benchmarks/results/recon_steps/NAME.json (``--out-dir`` for another folder). ``ucd_input`` is the UCD in
the target file's units (``ucd`` × the normalisation scale): compare those across frames.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from pathlib import Path

import lightning as L
import torch
from hydra import compose, initialize_config_dir

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from deepcurrents.eval.meshing import extract_surface  # noqa: E402
from deepcurrents.experiments.runner import build  # noqa: E402
from deepcurrents.models.reconstruction import reconstruction_metrics  # noqa: E402


class UcdProbe(L.Callback):
    """Training CPU seconds, an EMA of the current's weights, and the mesh's UCD at the chosen steps."""

    def __init__(self, evals: set[int], ema: float, ucd_samples: int, out: Path):
        self.evals, self.ema_decay, self.ucd_samples, self.out = evals, ema, ucd_samples, out
        self.cpu, self.t0, self.ema, self.rows = 0.0, 0.0, None, []

    def on_train_start(self, trainer, module):
        self.t0 = time.process_time()

    def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx):
        self.cpu += time.process_time() - self.t0
        if self.ema_decay > 0:
            with torch.no_grad():
                if self.ema is None:
                    self.ema = copy.deepcopy(module.current)
                for pe, pm in zip(self.ema.parameters(), module.current.parameters(), strict=True):
                    pe.lerp_(pm, 1 - self.ema_decay)
        if trainer.global_step in self.evals:
            for tag, current in (("weights", module.current), ("ema", self.ema)):
                if current is not None:
                    self.evaluate(module, current, tag, trainer.global_step)
        self.t0 = time.process_time()

    def evaluate(self, module, current, tag: str, step: int) -> None:
        trained, module.current = module.current, current  # mesh_options and the metrics read module.current
        current.eval()
        started = time.process_time()
        try:
            with torch.no_grad():
                result = extract_surface(current, **module.mesh_options())
            metrics = reconstruction_metrics(module, result.mesh, self.ucd_samples, 12345)
            closed = result.zipped_loops
        except Exception as err:  # noqa: BLE001 — e.g. no level set yet: recorded, not fatal
            metrics, closed = {"ucd": None, "ucd_reverse": None, "error": str(err)[:200]}, None
        current.train()
        module.current = trained
        scale = float(module.target_scale)
        row = {"tag": tag, "step": step, "cpu_s": round(self.cpu, 2), "s_per_step": round(self.cpu / step, 4),
               "ucd": metrics["ucd"], "ucd_reverse": metrics["ucd_reverse"],
               "ucd_input": metrics["ucd"] * scale if metrics["ucd"] is not None else None,
               "scale": scale, "loops_closed": closed, "eval_cpu_s": round(time.process_time() - started, 1)}
        print(json.dumps(row), flush=True)
        self.rows.append(row)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("name")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--evals", default="", help="comma-separated steps (the last step is always evaluated)")
    parser.add_argument("--ema", type=float, default=0.0, help="also evaluate an EMA of the weights (decay)")
    parser.add_argument("--ucd-samples", type=int, default=100_000)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out-dir", default=str(ROOT / "benchmarks" / "results" / "recon_steps"),
                        help="folder for NAME.json (default benchmarks/results/recon_steps)")
    args, overrides = parser.parse_known_args()
    overrides = [o for o in overrides if o != "--"]
    torch.set_num_threads(args.threads)
    evals = {int(s) for s in args.evals.split(",") if s} | {args.steps}
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="train", overrides=["experiment=recon_hand", "preset=cpu", "logger=none",
                                                      "data.num_workers=0", f"trainer.max_steps={args.steps}",
                                                      *overrides])
    L.seed_everything(int(cfg.seed), verbose=False)
    datamodule, module = build(cfg)
    out = Path(args.out_dir).expanduser()
    out.mkdir(parents=True, exist_ok=True)
    probe = UcdProbe(evals, args.ema, args.ucd_samples, out)
    trainer = L.Trainer(max_steps=args.steps, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                        enable_model_summary=False, callbacks=[probe], accelerator="cpu", devices=1)
    trainer.fit(module, datamodule=datamodule)
    (out / f"{args.name}.json").write_text(json.dumps({"overrides": overrides, "ema": args.ema,
                                                       "rows": probe.rows}, indent=1))


if __name__ == "__main__":
    main()
