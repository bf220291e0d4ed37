"""Every row of the paper's authors' reference right-hand side (reference/golden-rhs.jsonl)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from mmg import all_forces, derivatives, efd_parameters
from mmg.model import hydrodynamic_forces  # noqa: F401  (compiled alongside)
from mmg.propeller import advance_ratio, propeller_forces, wake_factor
from mmg.rudder import rudder_inflow
from tests.conftest import kernels

pytestmark = pytest.mark.kernels(*kernels((), "derivatives"))

FORCE_NAMES = ("XH", "YH", "NH", "XP", "YP", "NP", "XR", "YR", "NR", "XA", "YA", "NA")
ROWS = [
    json.loads(line)
    for line in (Path(__file__).resolve().parents[1].parent / "shared/reference/golden-rhs.jsonl")
    .read_text()
    .splitlines()
    if line.strip()
]


def test_there_are_twelve_golden_rows():
    assert len(ROWS) == 12


@pytest.mark.parametrize("row", ROWS, ids=[f"row{i}" for i in range(len(ROWS))])
def test_derivatives_match_authors_implementation(row):
    p = efd_parameters()
    x = np.array(row["state_x_u_y_vm_psi_r"])
    u = np.array([row["delta_rad"], row["n_rps"]])
    w = np.array([row["UT"], row["gammaT"]])
    expected = np.array(row["xdot_udot_ydot_vmdot_psidot_rdot"])
    got = derivatives(x, u, w, p)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("row", ROWS, ids=[f"row{i}" for i in range(len(ROWS))])
def test_twelve_force_components_match(row):
    p = efd_parameters()
    _x0, u, _y0, v_m, psi, r = row["state_x_u_y_vm_psi_r"]
    forces = all_forces(
        u, v_m, r, psi, row["delta_rad"], row["n_rps"], row["UT"], row["gammaT"], p.theta, p.ship
    )
    expected = np.array([row["forces_N_Nm"][k] for k in FORCE_NAMES])
    np.testing.assert_allclose(np.array(forces), expected, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("row", ROWS, ids=[f"row{i}" for i in range(len(ROWS))])
def test_rudder_inflow_and_angle_of_attack(row):
    p = efd_parameters()
    th, sh = p.theta, p.ship
    _x0, u, _y0, v_m, _psi, r = row["state_x_u_y_vm_psi_r"]
    n_p, delta = row["n_rps"], row["delta_rad"]
    one_minus_w = wake_factor(u, v_m, r, th, sh)
    J_s = advance_ratio(u, n_p, sh)
    K_T = propeller_forces(u, n_p, J_s, one_minus_w, th, sh)[3]
    u_R, v_R = rudder_inflow(u, v_m, r, n_p, one_minus_w, K_T, th, sh)
    assert u_R == pytest.approx(row["uR"], rel=1e-6, abs=1e-9)
    assert v_R == pytest.approx(row["vR"], rel=1e-6, abs=1e-9)
    alpha_R = delta - math.atan2(v_R, u_R)
    diff = (alpha_R - row["aR"] + math.pi) % (2 * math.pi) - math.pi  # compare modulo 2 pi
    assert abs(diff) < 1e-6
