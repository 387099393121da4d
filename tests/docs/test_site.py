"""The documentation: the site builds with warnings as errors (broken links, missing references, docstrings the
reference cannot read), and the README stays a front door whose links all land."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest
from conftest import ROOT


def test_the_site_builds_strictly(tmp_path):
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    for page in ("index.html", "python-api/index.html", "reference/api/index.html", "tutorials/tutorial/index.html",
                 "results/index.html"):
        assert (tmp_path / "site" / page).is_file(), page
    api = (tmp_path / "site" / "reference" / "api" / "index.html").read_text()
    assert "minimal_surface" in api and "mass_bound" in api  # generated from the docstrings


README = (ROOT / "README.md").read_text()


def test_the_readme_is_a_front_door():
    assert len(README.splitlines()) <= 250
    dated = [line for line in README.splitlines()
             if re.search(r"20\d\d-\d\d-\d\d|\b(Jan|Feb|Mar|Apr|May|Jun|Jul|Aug|Sep|Oct|Nov|Dec)[a-z]* 20\d\d", line)]
    assert not dated, dated
    for command in ("make run", "make test", "import deepcurrents", "experiment=fig4", "experiment=table1"):
        assert command in README


@pytest.mark.parametrize("target", sorted(set(re.findall(r"\]\(([^)#\s]+)", README))))
def test_every_link_of_the_readme_lands(target):
    assert target.startswith("http") or (ROOT / target).exists(), target
