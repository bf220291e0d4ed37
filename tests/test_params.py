"""The parameter table: order, EFD values, search domain, vector and JSON round trips."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mmg import (
    N_THETA,
    PARAMETER_NAMES,
    ParameterError,
    Parameters,
    bounds,
    efd_parameters,
)


def test_fifty_seven_parameters_in_documented_order():
    assert N_THETA == 57
    assert PARAMETER_NAMES[:3] == ("m_x", "m_y", "I_zz_J_zz")
    assert PARAMETER_NAMES[-1] == "N3"
    assert len(set(PARAMETER_NAMES)) == 57


def test_efd_values_from_the_reference():
    th = efd_parameters().theta
    assert th.X_vr == 0.4535  # not -0.0081 (reference: disagreement between sources)
    assert th.C10 == -0.233 and th.k_xPR == 0.144 and th.N3 == -0.00088
    assert efd_parameters().ship.k_1 == -0.3323


def test_search_domain_with_the_papers_exceptions():
    lo, hi = bounds()
    p = efd_parameters()
    v = p.vector()
    idx = {n: i for i, n in enumerate(PARAMETER_NAMES)}
    assert np.all(lo < hi)
    assert np.all((lo <= v) & (v <= hi))
    for name in ("m_x", "m_y", "I_zz_J_zz"):
        assert (lo[idx[name]], hi[idx[name]]) == pytest.approx(
            (0.7 * v[idx[name]], 1.3 * v[idx[name]])
        )
    assert (lo[idx["Y_v"]], hi[idx["Y_v"]]) == pytest.approx((-3.728, -0.03728))
    assert (lo[idx["N_r"]], hi[idx["N_r"]]) == pytest.approx((-0.4849, -0.004849))
    assert (lo[idx["t_P"]], hi[idx["t_P"]]) == pytest.approx((0.022, 2.2))
    assert (lo[idx["w_P0"]], hi[idx["w_P0"]]) == pytest.approx((0.0614, 6.14))
    assert (lo[idx["C_D"]], hi[idx["C_D"]]) == pytest.approx((-9.665, 9.665))


def test_vector_and_json_round_trip(tmp_path):
    p = efd_parameters().replace(a_H=0.5, l_R=-2.0)
    q = Parameters.from_vector(p.vector())
    assert q == p
    path = tmp_path / "p.json"
    p.save_json(path, objective="J2", seed=1)
    r = Parameters.load_json(path)
    assert r == p
    assert json.loads(path.read_text())["metadata"]["seed"] == 1


@pytest.mark.parametrize(
    "payload,message",
    [
        ("{", "not valid JSON"),
        ('{"theta": {"m_x": 1}}', "missing parameter"),
        ("[1, 2]", "expected a JSON object"),
    ],
)
def test_bad_parameter_files_are_named(tmp_path, payload, message):
    path = tmp_path / "bad.json"
    path.write_text(payload)
    with pytest.raises(ParameterError, match=message) as err:
        Parameters.load_json(path)
    assert str(path) in str(err.value)


def test_non_numeric_entry_is_named(tmp_path):
    d = efd_parameters().to_dict()
    d["theta"]["a_H"] = "big"
    path = tmp_path / "p.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ParameterError, match=r"theta\.a_H must be a number"):
        Parameters.load_json(path)


def test_unknown_parameter_name_in_replace():
    with pytest.raises(ParameterError, match="unknown parameter"):
        efd_parameters().replace(a_h=1.0)
