"""Loading any DeepCurrents checkpoint: the model's class and run configuration travel inside it
(``checkpoint["deepcurrents"] = {"module": class path, "config": run config}``, see models.base).

Apps (render, extract, evaluate, …) look at a model through :func:`viewable_current`: a module exposes the
current to look at as its ``current`` attribute (a NeuralCurrent-like module); families give one member
per training shape (``member``/``latent``/``shape_loops``); :func:`current_to_view` picks it.
"""

from __future__ import annotations

import importlib
import pickle
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from deepcurrents.errors import UserInputError
from deepcurrents.eval.meshing import mesh_method
from deepcurrents.models.base import CHECKPOINT_KEY, DeepCurrentsModule
from deepcurrents.models.current_module import input_frame
from deepcurrents.models.reconstruction import TargetGeometry


class CheckpointError(UserInputError):
    """A checkpoint that cannot be used: missing, truncated, foreign, or of the wrong model kind."""


def check_archive(path: Path, ckpt_path: str | Path) -> None:
    """CheckpointError unless ``path`` is the zip archive torch.save writes with every entry's checksum intact: a
    byte flipped in a copy or on disk would otherwise load without a word (torch reads entries without checking
    them). A plain pickle (or torch.save's legacy format) is refused unread."""
    if not zipfile.is_zipfile(path):
        with open(path, "rb") as fh:
            head = fh.read(1)
        if head == b"\x80":  # a pickle's protocol opcode
            raise CheckpointError(f"ckpt_path='{ckpt_path}' is a plain Python pickle (or torch.save's legacy format), "
                                  "not a checkpoint; it is refused unread, because opening it could run code.")
        raise CheckpointError(f"ckpt_path='{ckpt_path}' is not a readable PyTorch checkpoint (truncated or corrupt: "
                              "not the zip archive torch.save writes).")
    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as err:
        raise CheckpointError(f"ckpt_path='{ckpt_path}' is not a readable PyTorch checkpoint (truncated or corrupt: "
                              f"{type(err).__name__}).") from None
    if bad is not None:
        raise CheckpointError(f"ckpt_path='{ckpt_path}' is corrupt: its entry '{bad}' fails its checksum (a damaged "
                              "copy or disk); use an earlier checkpoint or copy it again.")


def read_checkpoint(ckpt_path: str | Path) -> dict[str, Any]:
    """The checkpoint's dictionary (on the CPU), or CheckpointError naming the file and what is wrong.

    Read with ``weights_only=True``: only tensors and plain data are unpickled, so a crafted file cannot run
    code (ours hold nothing else, models.checkpointing.plain_data); one that needs more is refused."""
    path = Path(str(ckpt_path)).expanduser()
    if not path.exists():
        raise CheckpointError(f"ckpt_path='{ckpt_path}' does not exist.")
    if path.is_dir():
        last = next((p for p in (path / "checkpoints" / "last.ckpt", path / "last.ckpt") if p.is_file()), None)
        hint = f"; this run's last one is ckpt_path='{last}'" if last is not None else \
            " (a run keeps its checkpoints in checkpoints/last.ckpt)"
        raise CheckpointError(f"ckpt_path='{ckpt_path}' is a directory, not a checkpoint file{hint}.")
    if not path.is_file():
        raise CheckpointError(f"ckpt_path='{ckpt_path}' is not a file.")
    check_archive(path, ckpt_path)
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        found = re.search(r"GLOBAL ([\w.]+)", str(err))  # the object the file asks to import and call
        if found is None:  # not a pickle we can read at all (text, random bytes)
            raise CheckpointError(f"ckpt_path='{ckpt_path}' is not a readable PyTorch checkpoint (truncated or "
                                  "corrupt: UnpicklingError).") from None
        raise CheckpointError(
            f"ckpt_path='{ckpt_path}' holds Python objects other than tensors and plain data "
            f"({found.group(1)}); it is refused, because opening it could run code (DeepCurrents checkpoints "
            "hold only data)."
        ) from None
    except Exception as err:  # any other failure to parse the file: torn, not a checkpoint, corrupt
        raise CheckpointError(
            f"ckpt_path='{ckpt_path}' is not a readable PyTorch checkpoint (truncated or corrupt: "
            f"{type(err).__name__})."
        ) from None
    if not isinstance(ckpt, dict) or "state_dict" not in ckpt:
        raise CheckpointError(f"ckpt_path='{ckpt_path}' is not a Lightning checkpoint (no state_dict).")
    info = ckpt.get(CHECKPOINT_KEY)
    if not isinstance(info, dict) or "module" not in info:
        raise CheckpointError(
            f"ckpt_path='{ckpt_path}' was not written by DeepCurrents (no '{CHECKPOINT_KEY}' entry naming "
            "its model); train one with `python train.py experiment=…`."
        )
    return ckpt


# model classes that moved: checkpoints written before the move name the old path
MOVED_CLASSES = {
    "deepcurrents.models.closest_point.ClosestPointModule": "deepcurrents.baselines.closest_point.ClosestPointModule",
    "deepcurrents.models.grid.GridModule": "deepcurrents.baselines.grid.GridModule",
}


def module_class(class_path: str, ckpt_path: str | Path = "") -> type[DeepCurrentsModule]:
    """The LightningModule class named by a checkpoint, checked to be a DeepCurrents model."""
    class_path = MOVED_CLASSES.get(str(class_path), str(class_path))
    module_name, _, name = class_path.rpartition(".")
    try:
        cls = getattr(importlib.import_module(module_name), name)
    except (ImportError, AttributeError, ValueError):
        raise CheckpointError(
            f"ckpt_path='{ckpt_path}' was written by model class '{class_path}', which this version of "
            "DeepCurrents does not have."
        ) from None
    if not (isinstance(cls, type) and issubclass(cls, DeepCurrentsModule)):
        raise CheckpointError(
            f"ckpt_path='{ckpt_path}' names '{class_path}', which is not a DeepCurrents model."
        )
    return cls


def file_frame(module) -> tuple[float, np.ndarray] | None:
    """(scale, offset) from the model's box to the coordinates of the files the run was given, input = model ·
    scale + offset: a reconstruction's normalised target, else a normalised curve's (the frame of the run's own
    mesh.ply); None where the two coincide."""
    if getattr(module, "target_scale", None) is not None:
        frame = TargetGeometry.frame(module)
        if frame is not None:
            return frame
    return input_frame((getattr(module, "hparams", None) or {}).get("boundary") or {})


def article(name: str) -> str:
    """``name`` after its indefinite article (a CurrentModule, an AutodecoderModule)."""
    return f"{'an' if name[:1].upper() in 'AEIOU' else 'a'} {name}"


def run_kind(cls: type) -> str:
    """The kind of run a model class is trained by, in the documentation's words (for messages)."""
    words = {"AutodecoderModule": "a family run's checkpoint (experiment=latent_*)",
             "ReconstructionModule": "a reconstruction's checkpoint (experiment=recon_*)",
             "CurrentModule": "a minimal surface's checkpoint (experiment=minimal_*)",
             "GridModule": "the grid method's checkpoint (experiment=minimal_grid)",
             "ClosestPointModule": "the closest-point baseline's checkpoint (experiment=recon_baseline)"}
    return next((words[c.__name__] for c in cls.__mro__ if c.__name__ in words), f"{article(cls.__name__)} checkpoint")


def load_module(ckpt_path: str | Path, map_location: str | torch.device | None = "cpu",
                expected: type | tuple[type, ...] | None = None) -> DeepCurrentsModule:
    """Rebuilds the model of any DeepCurrents checkpoint (class and hyperparameters from the file), in eval
    mode, with ``run_config`` restored. ``expected``: the model kinds the caller can use (else error)."""
    ckpt = read_checkpoint(ckpt_path)
    info = ckpt[CHECKPOINT_KEY]
    cls = module_class(info["module"], ckpt_path)
    if expected is not None and not issubclass(cls, expected):
        names = " or ".join(run_kind(c) for c in (expected if isinstance(expected, tuple) else (expected,)))
        raise CheckpointError(f"ckpt_path='{ckpt_path}' is {run_kind(cls)} ({cls.__name__}), but this needs "
                              f"{names}.")
    hparams = dict(ckpt.get("hyper_parameters") or {})
    try:
        module = cls(**hparams)
    except UserInputError:
        raise
    except TypeError as err:
        raise CheckpointError(
            f"ckpt_path='{ckpt_path}': its {cls.__name__} hyperparameters do not fit this version ({err})."
        ) from None
    except Exception as err:  # the constructors trust their settings (checked before a run trains): a crafted file's
        raise CheckpointError(f"ckpt_path='{ckpt_path}': its {cls.__name__} hyperparameters cannot build the model "
                              f"({type(err).__name__}: {err}).") from None
    try:
        module.load_state_dict(ckpt["state_dict"], strict=True)
    except RuntimeError:
        raise CheckpointError(
            f"ckpt_path='{ckpt_path}': its weights do not fit {article(cls.__name__)} built from its own "
            "hyperparameters (the file was edited or comes from another version)."
        ) from None
    if hasattr(module, "on_load_checkpoint"):
        module.on_load_checkpoint(ckpt)
    module.run_config = info.get("config")
    module.loaded_step = int(ckpt.get("global_step", 0))
    module.eval()
    if map_location is not None:
        module.to(map_location)
    return module


# settings of ``data`` that say which problem a run solves (the rest are sizes, workers, augmentation)
PROBLEM_KEYS = ("_target_", "dim", "curve", "curve_vertices", "curve_scale", "points", "signs", "radius", "mesh",
                "category", "source", "index", "path", "max_meshes", "held_out")


FILE_KEYS = ("curve", "points", "mesh", "path")  # compared as the files they name, not as strings


def _files(value: Any) -> Any:
    """The files a data setting names, resolved (a trailing slash, a symlink, a relative path, or a folder given as
    the list of its meshes name the same files); other values (a named curve, null) as they are."""
    from deepcurrents.data.family import family_files

    names = [value] if isinstance(value, str) else value if isinstance(value, (list, tuple)) else None
    if not names or not all(isinstance(n, str) and Path(n).expanduser().exists() for n in names):
        return value
    try:  # a folder's meshes as a family reads them
        return [str(p.expanduser().resolve()) for name in names for p in family_files(name)]
    except UserInputError:  # a folder without meshes: its own name
        return [str(Path(n).expanduser().resolve()) for n in names]


def _same(a: Any, b: Any) -> bool:
    """Nested plain data (and tensors) equal up to float rounding (a boundary read back from a file)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    try:
        x, y = torch.as_tensor(a, dtype=torch.float64), torch.as_tensor(b, dtype=torch.float64)
    except (TypeError, ValueError, RuntimeError):
        if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
            return len(a) == len(b) and all(_same(u, v) for u, v in zip(a, b, strict=True))
        return a == b
    return x.shape == y.shape and bool(torch.allclose(x, y, rtol=1e-6, atol=1e-9))


def check_resumable(ckpt_path: str | Path, module: DeepCurrentsModule) -> dict[str, Any]:
    """Checks, before training, that the checkpoint can continue the run ``module`` was built for: a
    DeepCurrents checkpoint (read safely, :func:`read_checkpoint`) of the same model kind, whose problem
    (boundary, target, training shapes) and weight shapes are this run's. → the checkpoint; else
    CheckpointError, one sentence saying what differs."""
    ckpt = read_checkpoint(ckpt_path)
    info = ckpt[CHECKPOINT_KEY]
    cls = module_class(info["module"], ckpt_path)
    if cls is not type(module):
        raise CheckpointError(
            f"ckpt_path='{ckpt_path}' holds {article(cls.__name__)}, but this run's config builds "
            f"{article(type(module).__name__)}; resume with the model it was trained with."
        )
    saved_cfg = info.get("config") if isinstance(info.get("config"), dict) else {}
    own_cfg = module.run_config or {}
    saved_data, own_data = saved_cfg.get("data") or {}, own_cfg.get("data") or {}
    for key in PROBLEM_KEYS:
        if key in saved_data and key in own_data and not _same(*(_files(d[key]) if key in FILE_KEYS else d[key]
                                                                 for d in (saved_data, own_data))):
            raise CheckpointError(
                f"ckpt_path='{ckpt_path}' was trained with data.{key}={saved_data[key]!r}, but this run has "
                f"data.{key}={own_data[key]!r}; resume with the data it was trained on."
            )
    saved_hp, own_hp = ckpt.get("hyper_parameters") or {}, dict(module.hparams)
    for key, what in (("boundary", "another boundary Γ"), ("shape_names", "other training shapes"),
                      ("loop_lengths", "other boundary loops")):
        if key in saved_hp and key in own_hp and not _same(saved_hp[key], own_hp[key]):
            raise CheckpointError(
                f"ckpt_path='{ckpt_path}' was trained for {what} than this run's data gives (a file's contents, or "
                "a setting that reshapes it such as data.normalize or data.max_vertices_per_loop, differ); resume "
                "with the data and settings it was trained with."
            )
    saved_sd, own_sd = ckpt["state_dict"], module.state_dict()
    if not isinstance(saved_sd, dict):
        raise CheckpointError(f"ckpt_path='{ckpt_path}' has no weights (its state_dict is not a dictionary).")
    for name, buffer in module.named_buffers():
        if name.startswith("target_") and name in saved_sd and not _same(saved_sd[name], buffer):
            raise CheckpointError(
                f"ckpt_path='{ckpt_path}' was trained on another target surface than this run's data gives "
                "(the same settings, but the file differs); resume with the data it was trained on."
            )
    for name, tensor in own_sd.items():
        other = saved_sd.get(name)
        if not isinstance(other, torch.Tensor):  # a part this run's settings add (a recipe's, a model.* option's)
            raise CheckpointError(
                f"ckpt_path='{ckpt_path}' has no '{name}', which this run's settings add (a recipe= or model.* "
                "option it was not trained with); resume with the settings it was trained with."
            )
        if other.shape != tensor.shape:
            grid = getattr(module, "resolution", None)
            if name == "current.phi" and grid is not None:  # the grid method's one array: name its resolution
                raise CheckpointError(
                    f"ckpt_path='{ckpt_path}' holds a {other.shape[0]}³ grid, but this run's config builds "
                    f"{grid}³ (model.grid.resolution, or the network size it is matched to); resume with the "
                    f"resolution it was trained with (model.grid.resolution={other.shape[0]})."
                )
            raise CheckpointError(
                f"ckpt_path='{ckpt_path}': its weights do not fit the {type(module).__name__} this run's config "
                f"builds ('{name}' differs: model.net / model.rff / model.* sizes are not the ones it was "
                "trained with)."
            )
    # Adam's state is per parameter group: a different count would be refused deep inside Lightning's restore
    states = ckpt.get("optimizer_states")
    saved = states[0] if isinstance(states, list) and states and isinstance(states[0], dict) else {}
    saved_groups, own_groups = saved.get("param_groups"), module.parameter_groups(1.0)
    if isinstance(saved_groups, list) and len(saved_groups) != len(own_groups):
        raise CheckpointError(
            f"ckpt_path='{ckpt_path}' was trained with {len(saved_groups)} learning-rate group(s) but this run's "
            f"config makes {len(own_groups)} (model.latent_lr_factor is 1 on one side only); resume with the "
            "settings it was trained with."
        )
    return ckpt


def current_to_view(module, shape: int | None = None):
    """The current to look at in a model (duck-typed, no model classes imported): ``module.current``
    (single currents), or for a family the member of training shape ``shape`` (default 0) with its own
    latent code and boundary (``module.member(module.latent(i), module.shape_loops(i))``). Raises
    ValueError when there is none."""
    if shape is None and getattr(module, "current", None) is not None:
        return module.current
    if all(callable(getattr(module, name, None)) for name in ("member", "latent", "shape_loops")):
        index = 0 if shape is None else shape
        if callable(getattr(module, "check_shape_index", None)):
            index = module.check_shape_index(index, "shape")
        return module.member(module.latent(index), module.shape_loops(index))
    if shape is not None:
        raise ValueError(f"shape={shape} was given, but this {type(module).__name__} holds a single current")
    raise ValueError(f"{article(type(module).__name__)} has neither a `current` nor family members to look at")


def viewable_current(module: torch.nn.Module, ckpt_path: str | Path = "", shape: int | None = None):
    """The current an app looks at (:func:`current_to_view`), or CheckpointError saying why not."""
    if shape is not None and getattr(module, "current", None) is not None:
        raise CheckpointError(f"shape={shape} picks one shape of a family, but ckpt_path='{ckpt_path}' holds a "
                              "single current; leave shape unset.")
    try:
        return current_to_view(module, shape)
    except ValueError as err:
        if isinstance(err, UserInputError):
            raise
        raise CheckpointError(f"ckpt_path='{ckpt_path}' has no current to look at: {err}.") from None


def run_evaluation(module: Any) -> dict[str, Any]:
    """The run's ``evaluation`` node as a checkpoint carries it (the module's, else its run config's; {})."""
    return dict(getattr(module, "evaluation", None) or (getattr(module, "run_config", None) or {}).get("evaluation")
                or {})


def mesh_settings(module: Any, shape: int | None = None, **overrides: Any) -> dict[str, Any]:
    """``extract_surface`` keyword arguments: the run's ``evaluation.mesh`` settings, then ``overrides``
    (None values are ignored). Families mesh a member inside its training shape's box
    (``module.meshing_bounds``) and reconstructions inside their target's (``module.target_bounds``),
    since their surfaces reach beyond Γ's box."""
    settings = dict(run_evaluation(module).get("mesh") or {})
    settings.update({k: v for k, v in overrides.items() if v is not None})
    if settings.get("bounds") is None and callable(getattr(module, "meshing_bounds", None)):
        # the app's padding= (ignored before: the family's box came from the run's own padding)
        settings["bounds"] = module.meshing_bounds([0 if shape is None else shape], padding=overrides.get("padding"))
        settings.pop("padding", None)
    elif settings.get("bounds") is None and callable(getattr(module, "target_bounds", None)):
        # reconstructions: the run meshed over its target's box, so must the apps
        settings["bounds"] = module.target_bounds(settings.get("padding", 0.15))
    if callable(getattr(module, "closed_pieces_on", None)):  # and kept the closed pieces on its target
        settings["closed_on"] = module.closed_pieces_on()
    return mesh_method(settings, getattr(module, "mesh_method", "phase"))


def resolve_device(device: str) -> torch.device:
    """'auto' → CUDA if available else CPU; anything else as torch.device, checked to exist."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(device)
    except RuntimeError:
        raise UserInputError(f"device='{device}' is not a device name (auto, cpu, cuda, cuda:1…).") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise UserInputError(f"device='{device}' was asked for, but no CUDA GPU is available here.")
    return dev


# The state of a current that is its problem's, not its training's: Γ (loops or 2D poles)
BOUNDARY_BUFFERS = ("current.vertices", "current.loop_sizes", "current.poles", "current.signs")


def warm_start(module: DeepCurrentsModule, ckpt_path: str | Path) -> int:
    """Copies the network of another run's checkpoint into ``module`` (``init_from``): every tensor of its current f
    (features, MLP, grid) but Γ, which stays this run's; the step, the optimiser and the target are not taken. The
    checkpoint must be of the same model kind with the same network settings, else CheckpointError saying which
    tensor differs. → the number of tensors copied."""
    ckpt = read_checkpoint(ckpt_path)
    saved_class = str(ckpt[CHECKPOINT_KEY]["module"])
    own = f"{type(module).__module__}.{type(module).__qualname__}"
    if MOVED_CLASSES.get(saved_class, saved_class) != own:
        raise CheckpointError(f"init_from='{ckpt_path}' is {run_kind(module_class(saved_class, ckpt_path))}, not "
                              f"{run_kind(type(module))} like this run, so its network cannot start this one.")
    state = module.state_dict()
    network = {k: v for k, v in ckpt["state_dict"].items() if k.startswith("current.") and k not in BOUNDARY_BUFFERS}
    for key, value in network.items():
        if key not in state or tuple(state[key].shape) != tuple(value.shape):
            here = tuple(state[key].shape) if key in state else "absent"
            raise CheckpointError(f"init_from='{ckpt_path}' has a network of other settings ({key}: "
                                  f"{tuple(value.shape)} there, {here} here); a warm start needs the same model.net, "
                                  "model.rff and model.grid_encoding.")
    module.load_state_dict(network, strict=False)
    return len(network)
