"""The shipped best parameters reproduce the numbers published in docs/results.md."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sweep.evaluate import main
from tests.conftest import kernels

pytestmark = pytest.mark.kernels(*kernels((), "moments"))

SHIPPED = Path(__file__).resolve().parents[1] / "results" / "best_params.json"


def test_shipped_parameters_reproduce_their_test_metrics(data_dir, tmp_path, monkeypatch):
    meta = json.loads(SHIPPED.read_text())["metadata"]
    assert {"objective", "train", "seed", "budget", "commit"} <= set(meta)
    monkeypatch.setenv("MMG_DATA_DIR", str(data_dir))
    out = tmp_path / "j.json"
    assert main(["--params", str(SHIPPED), "--set", "test", "--json", str(out)]) == 0
    table = json.loads(out.read_text())
    published = meta["test"]
    for J in ("J1", "J2", "J3"):
        for column, subset in (("Test-B-S", "B-S"), ("Test-B-P", "B-P"), ("Total", "total")):
            assert table[J][column] == pytest.approx(published[J][subset], rel=1e-9)
    # the identified model beats EFD on the test-set Total (EFD J2: 5498.6)
    assert table["J2"]["Total"] < 5498.6
