"""How far to trust a diagnosed model: the JSON-ready summary of its intervals and manoeuvres."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mmg import get_effect
from sweep.data.datasets import load_split
from sweep.data.parameters import load_parameters
from sweep.data.standard_manoeuvres import find_manoeuvre
from sweep.diagnose.trust import trust_markdown, trust_of
from sweep.diagnose.windows import cut_windows
from sweep.identification.vector import with_effects
from tests.conftest import kernels

DOCS = Path(__file__).resolve().parents[1] / "docs" / "diagnosis-real"

pytestmark = pytest.mark.kernels(
    *kernels((), "simulate", "derivatives"),
    *kernels(("discovered:N_s3b",), "simulate", "derivatives"),
)


def test_the_diagnosed_model_before_and_after(data_dir):
    """The real diagnosis's models on their Train-R windows with J2: the summary is JSON
    (no NaN), its counts cover every parameter, the effect's parameter has its interval, the
    manoeuvres their intervals over the draws; the same seed gives the same summary; a
    single window is too few to judge and comes back as an error."""
    windows = cut_windows(list(load_split("R").load(str(data_dir)).values()))
    test = load_split("paper").load(str(data_dir))
    found = find_manoeuvre(test["Test-T"], "Test-T")
    assert found is not None
    runs = [found]
    out = {}
    before = load_parameters(str(DOCS / "params_before.json"))
    # the model with a yaw moment -U^2 sin 3 beta, at the value Train-R gave it
    after = with_effects(before, (get_effect("discovered:N_s3b"),), [-0.0097])
    for stage, params in (("before", before), ("after", after)):
        out[stage] = trust_of(params, windows, "J2", np.random.default_rng(1), runs, draws=4)
        s = json.loads(json.dumps(out[stage], allow_nan=False))
        assert sum(s["counts"].values()) == s["parameters"] == 57 + (stage == "after")
        assert 0.0 < s["fraction_determined"] < 1.0 and s["draws"] == 4
        advance = next(r for r in s["manoeuvres"] if r["key"] == "turning.advance")
        assert advance["limit"] == 4.5 and 0 < advance["samples"] <= 4
        assert {r["run"] for r in s["recorded"]} == {"Test-T"}
    assert out["before"]["effects"] == []
    (effect,) = out["after"]["effects"]
    assert effect["name"] == "discovered:N_s3b.C_N_s3b"
    assert effect["lower"] <= effect["estimate"] <= effect["upper"]
    again = trust_of(
        load_parameters(str(DOCS / "params_before.json")), windows, "J2",
        np.random.default_rng(1), runs, draws=4,
    )  # fmt: skip
    assert {k: v for k, v in again.items() if k != "seconds"} == {
        k: v for k, v in out["before"].items() if k != "seconds"
    }
    text = trust_markdown(out)
    assert "| parameters determined |" in text and "discovered:N_s3b.C_N_s3b" in text
    failed = trust_of(load_parameters("efd"), windows[:1], "J2", np.random.default_rng(0))
    assert failed["error"].startswith("ValueError") and "subsequences" in failed["error"]
    assert "not computed" in trust_markdown({"before": failed, "after": out["after"]})
