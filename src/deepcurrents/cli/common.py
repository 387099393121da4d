"""Plumbing shared by the checkpoint apps (``python -m deepcurrents.cli.render|extract|evaluate ckpt_path=…``):
structured Hydra configs without config files, outputs next to the checkpoint, one-sentence errors.

Each app registers its dataclass with :func:`register_app` and decorates its main with
``@hydra.main(version_base="1.3", config_path=None, config_name=NAME)``. The apps write only their own
files: no Hydra run directory, no ``.hydra`` folder, logs to the terminal.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import OmegaConf

from deepcurrents.errors import ConfigError, NonFiniteLossError, UserInputError

log = logging.getLogger("deepcurrents")


# the apps' log lines, bare, on stderr: their stdout is what they print (extract's and evaluate's JSON summary can be
# piped to jq or json.load); a whole config of Hydra's job_logging group, so that another choice replaces it cleanly
STDERR_LOGGING = {"version": 1, "formatters": {"simple": {"format": "%(message)s"}},
                  "handlers": {"console": {"class": "logging.StreamHandler", "formatter": "simple",
                                           "stream": "ext://sys.stderr"}},
                  "root": {"level": "INFO", "handlers": ["console"]}, "disable_existing_loggers": False}


def register_app(name: str, schema: type, doc: str | None = None) -> None:
    """Stores ``schema`` (a dataclass) as the primary config ``name`` in Hydra's ConfigStore; ``doc``
    heads ``--help``."""
    cs = ConfigStore.instance()
    cs.store(group="hydra/job_logging", name="stderr", node=STDERR_LOGGING)
    cs.store(name=f"{name}_schema", node=schema)
    header = (doc or f"python -m deepcurrents.cli.{name} ckpt_path=… [key=value …]").replace("${", "\\${")
    cs.store(name=name, node={
        "defaults": [f"{name}_schema", "_self_", {"override hydra/job_logging": "stderr"}],
        "hydra": {"run": {"dir": "."}, "output_subdir": None, "job": {"chdir": False},
                  "help": {"app_name": f"deepcurrents.{name}", "header": header,
                           "footer": "Settings are key=value overrides; --cfg job prints them."}},
    })


def output_dir(ckpt_path: str, out_dir: str | None, shape: int | None = None) -> Path:
    """``out_dir`` if given, else a folder named after the checkpoint beside it
    (``run/checkpoints/last.ckpt`` → ``run/checkpoints/last/``), and within it ``shape<i>/`` for one shape of a
    family (``shape=i``), so that the apps run on several shapes do not overwrite each other's files."""
    path = Path(out_dir) if out_dir else Path(ckpt_path).expanduser().with_suffix("")
    if not out_dir and shape is not None:
        path = path / f"shape{shape}"
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:  # a file in the way, a read-only disk, no permission
        where = f"out_dir='{out_dir}'" if out_dir else f"The folder beside the checkpoint, '{path}',"
        raise UserInputError(f"{where} cannot be created ({err.strerror or type(err).__name__}); choose a "
                             "writable out_dir=….") from None
    return path


def plain_file_name(value: Any, key: str = "name") -> str | None:
    """``value`` as an output file stem (None or "" → None: the app's default), or one sentence if it holds
    folders: the apps write into ``out_dir``, and a name with folders would write elsewhere or fail halfway."""
    if value is None or str(value) == "":
        return None
    name = str(value)
    if Path(name).name != name or name in (".", ".."):
        raise ConfigError(f"{key}='{name}' must be a plain file name without folders (the files go to out_dir).")
    return name


def exit_on_user_error(body: Callable[..., Any], *args: Any) -> Any:
    """``body(*args)``; a user error ends the process with one sentence on stderr and exit status 2
    (3 when the loss became NaN), never a traceback."""
    try:
        return body(*args)
    except UserInputError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    except NonFiniteLossError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(3)


def run_app(main: Callable[[Any], Any], cfg: Any) -> Any:
    """Runs an app's body: settings that must be given are checked first, then user errors end in one
    sentence (:func:`exit_on_user_error`)."""
    missing = sorted(OmegaConf.missing_keys(cfg))
    if missing:
        print(f"error: {', '.join(missing)} must be given, e.g. `{missing[0]}=…` on the command line.",
              file=sys.stderr)
        sys.exit(2)
    return exit_on_user_error(main, cfg)


def not_a_command(module: str) -> None:
    """For the helper modules' ``__main__``: one sentence and status 2 (``python -m deepcurrents.cli.families``
    exited 0 without a word)."""
    print(f"error: {module} is shared plumbing of the apps, not a command; the commands are "
          "python -m deepcurrents.cli.<train|render|extract|evaluate|interpolate|generate|make_dataset>.",
          file=sys.stderr)
    sys.exit(2)


if __name__ == "__main__":
    not_a_command("deepcurrents.cli.common")
