"""What each preset resolves to: the lengths and sizes of every experiment, composed from conf/ as
``python train.py experiment=NAME preset=P`` composes them, written as the table of ``docs/presets.md``.

    python -m deepcurrents.experiments.presets [docs/presets.md]
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig, OmegaConf

from deepcurrents.experiments.config import CONFIG_DIR

PRESETS = ("paper", "cpu")
# (column, the setting it shows; a tuple: the first that is set)
COLUMNS: tuple[tuple[str, Any], ...] = (
    ("steps", "trainer.max_steps"),
    ("lr", "model.optim.lr"),
    ("schedule", "model.optim.schedule"),
    ("ambient samples", "data.num_samples"),
    ("surface samples", "data.num_surface_samples"),
    ("meshes / batch", "data.meshes_per_batch"),
    ("frequencies (σ)", ("model.rff.num_frequencies", "model.rff.sigma")),
    ("MLP", ("model.net.depth", "model.net.width")),
    ("grid", "model.grid.resolution"),
    ("mesh resolution", "evaluation.mesh.resolution"),
    ("mass samples", "evaluation.mass_samples"),
)


def experiments(config_dir: str = CONFIG_DIR) -> list[str]:
    """The experiments of conf/experiment/, by name."""
    return sorted(p.stem for p in (Path(config_dir) / "experiment").glob("*.yaml"))


def _schedule(cfg: DictConfig) -> str:
    """The learning-rate schedule in a few words: "× gamma / step_size" or "cosine (warm-up)"."""
    optim = OmegaConf.select(cfg, "model.optim")
    if optim is None:
        return ""
    if optim.get("schedule", "step") == "cosine":
        return f"cosine, {100 * float(optim.get('warmup', 0)):g} % warm-up, to {float(optim.get('min_factor', 0)):g}×"
    return f"× {optim.get('gamma')} every {optim.get('step_size')}"


def _cell(cfg: DictConfig, key: Any) -> str:
    if key == "model.optim.schedule":
        return _schedule(cfg)
    if isinstance(key, tuple):
        first, second = (OmegaConf.select(cfg, k) for k in key)
        if first is None:
            return ""
        return f"{first} × {second}" if key[0].endswith("depth") else f"{first} ({second})"
    value = OmegaConf.select(cfg, key)
    return "" if value is None else f"{value:g}" if isinstance(value, float) else str(value)


def resolved_rows(config_dir: str = CONFIG_DIR) -> list[list[str]]:
    """One row per experiment and preset: its name, preset, data and model kinds and the ``COLUMNS``. Suites (an
    experiment with ``suite.runs``) are listed by their members."""
    rows = []
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=config_dir, version_base="1.3"):
        for name in experiments(config_dir):
            for preset in PRESETS:
                cfg = compose(config_name="train", overrides=[f"experiment={name}", f"preset={preset}"])
                runs = OmegaConf.select(cfg, "suite.runs")
                if runs:
                    members = ", ".join(str(r.name) for r in runs)
                    rows.append([name, preset, "suite", members] + [""] * len(COLUMNS))
                    continue
                kinds = [str(OmegaConf.select(cfg, f"{g}._target_", default="")).rsplit(".", 1)[-1]
                         for g in ("data", "model")]
                cells = {column: _cell(cfg, key) for column, key in COLUMNS}
                if kinds[1] == "GridModule":  # ADMM: no learning rate or batch; the network block is for comparison
                    cells.update({"lr": "", "schedule": "", "ambient samples": "",
                                  "grid": cells["grid"] or "auto (the network's parameters)"})
                else:
                    cells["grid"] = ""
                rows.append([name, preset, *kinds, *cells.values()])
    GlobalHydra.instance().clear()
    return rows


def presets_table(config_dir: str = CONFIG_DIR) -> str:
    """docs/presets.md: the Markdown table of ``resolved_rows``."""
    header = ["experiment", "preset", "data", "model", *(c for c, _ in COLUMNS)]
    lines = [
        "# What the presets resolve to",
        "",
        "Generated from `conf/` by `python -m deepcurrents.experiments.presets docs/presets.md` (a test checks that it",
        "is current): every experiment under `preset=paper` (the authors' sizes) and `preset=cpu` (minutes on a",
        "laptop CPU), as `python train.py experiment=NAME preset=P` composes it. A preset's sizes for a kind of run",
        "live in `conf/preset/<preset>.yaml` and `conf/preset_sizes/{data,model}/<preset>_<kind>.yaml`; a recipe",
        "(`recipe=`) and the command line change them on top. Empty: the setting does not apply to that kind.",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    lines += ["| " + " | ".join(row) + " |" for row in resolved_rows(config_dir)]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    text = presets_table()
    if argv:
        Path(argv[0]).write_text(text)
    else:
        print(text, end="")


if __name__ == "__main__":
    main()
