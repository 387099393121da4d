"""docs/presets.md, the table of what each preset resolves to, is generated from conf/ and must be current."""

from __future__ import annotations

import pytest
from conftest import CONF_DIR, ROOT

from deepcurrents.experiments.presets import COLUMNS, presets_table, resolved_rows


@pytest.fixture(scope="module")
def rows() -> list[list[str]]:
    return resolved_rows(CONF_DIR)


def test_the_committed_table_is_what_the_configs_resolve_to():
    assert (ROOT / "docs" / "presets.md").read_text() == presets_table(CONF_DIR), (
        "docs/presets.md is stale: python -m deepcurrents.experiments.presets docs/presets.md")


def test_the_table_reads_the_presets_sizes(rows):
    """Spot checks against the configs' own numbers: the paper's minimal surface (1e5 steps, 4096 samples, 4 × 256)
    and the CPU reconstruction (1000 steps of 1024 + 1024 samples, meshed at 96)."""
    columns = ["experiment", "preset", "data", "model", *(c for c, _ in COLUMNS)]
    table = {(r[0], r[1]): dict(zip(columns, r, strict=True)) for r in rows}
    paper = table["minimal_trefoil", "paper"]
    assert (paper["steps"], paper["ambient samples"], paper["MLP"]) == ("100000", "4096", "4 × 256")
    hand = table["recon_hand", "cpu"]
    assert (hand["steps"], hand["ambient samples"], hand["surface samples"], hand["mesh resolution"]) == \
        ("1000", "1024", "1024", "96")
    assert table["table1", "cpu"]["data"] == "suite"
