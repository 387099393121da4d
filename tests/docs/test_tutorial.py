"""The tutorial notebook (docs/tutorials/tutorial.ipynb) runs from top to bottom, at tiny sizes, as a reader would
run it (its own kernel, a fresh folder): the site never shows a notebook that no longer works."""

from __future__ import annotations

import nbformat
import pytest
from conftest import ROOT
from nbclient import NotebookClient

TUTORIAL = ROOT / "docs" / "tutorials" / "tutorial.ipynb"


@pytest.mark.slow
def test_the_tutorial_runs(tmp_path, monkeypatch):
    monkeypatch.setenv("DEEPCURRENTS_TUTORIAL_TINY", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    notebook = nbformat.read(TUTORIAL, as_version=4)
    client = NotebookClient(notebook, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    printed = "".join(out.get("text", "") for cell in notebook.cells if cell.cell_type == "code"
                      for out in cell.get("outputs", []))
    assert "refused:" in printed and "plain Python pickle" in printed  # the crafted file was refused, in a sentence
    assert "border to the curve" in printed
    assert (tmp_path / "outputs").is_dir()  # the runs went where a reader's would (beside the notebook)
