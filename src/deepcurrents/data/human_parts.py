"""The human-part datasets on disk (paper §5.2): ``<root>/<source>/<category>/NNN.ply`` meshes of heads, hands,
forearms, arms, torsos and feet, as ``deepcurrents-make-dataset`` writes them (``data.human_parts_builder``)."""

from __future__ import annotations

from pathlib import Path

from deepcurrents.errors import UserInputError

CATEGORIES = ("heads", "hands", "forearms", "arms", "torsos", "feet")


class DatasetError(UserInputError):
    """A dataset that is missing or malformed (the message says how to build or fix it)."""



def dataset_path(root: str | Path, source: str, category: str, index: int) -> Path:
    """``root/source/category/NNN.ply``; DatasetError (saying how to build it) when it is not there, or naming the
    categories when ``category`` is none of them and no folder of that name exists."""
    folder = Path(root) / source / str(category)
    if not folder.is_dir():
        if category not in CATEGORIES:  # a misspelling: no `make data` would ever build that folder
            raise DatasetError(f"data.category={category!r} is not a dataset category; choose one of "
                               f"{', '.join(CATEGORIES)}.")
        hint = "run `make data`" if source == "anny" else \
            f"run `python -m deepcurrents.cli.make_dataset --source {source} ...`"
        raise DatasetError(f"Dataset directory '{folder}' does not exist; {hint} to build it.")
    files = sorted(folder.glob("*.ply"))
    if not files:
        raise DatasetError(f"Dataset directory '{folder}' has no .ply meshes; run `make data` to build it.")
    if not 0 <= index < len(files):
        raise DatasetError(f"data.index={index} is out of range: '{folder}' has {len(files)} meshes "
                           f"(0–{len(files) - 1}).")
    return files[index]
