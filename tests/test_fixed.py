"""An effect held at given values (mmg.fixed): part of the model, no parameters of its own."""

from __future__ import annotations

import pickle
import re

import numpy as np
import pytest

from mmg import Parameters, efd_parameters, get_effect, simulate
from mmg.fixed import fixed, is_fixed, kernel_effects, split_name
from mmg.integrate import derivatives_rows, effect_accelerations_rows
from mmg.kernel import load_kernel
from sweep.identification.vector import full_vector, joint_box, with_effects
from tests.conftest import SHARED_EFFECTS, kernels, shared_effects

#: every hook kind: forces (walk, the generated force_at), inputs and delay (lag), current,
#: observe (heading bias)
HELD = {
    "propeller_walk": (0.01, -0.004),
    "actuator_lag": (1.2, 0.5, 0.3, 0.0),
    "current": (0.05, 0.7),
    "heading_bias": (0.02, -0.01),
    "discovered:N_dnn+Y_t": (0.002, -0.003),
}


def held_effects() -> tuple:
    """The shared effects, each held: at the values of :data:`HELD`, the others at neutral."""
    return tuple(fixed(e, HELD.get(e.name, e.neutral())) for e in shared_effects())


# a held effect runs the kernel of the effect it holds: the shared one, nothing new to compile
pytestmark = pytest.mark.kernels(
    *kernels(SHARED_EFFECTS, "simulate", "derivatives", "accelerations")
)


def test_a_fixed_effect_is_rebuilt_by_name_and_has_no_parameters():
    walk = get_effect("propeller_walk")
    held = fixed(walk, (0.01, -0.004))
    assert held.name == "propeller_walk@fixed(C_Yw=0.01,C_Nw=-0.004)"
    assert held.params == () and is_fixed(held) and not is_fixed(walk)
    assert split_name(held.name) == ("propeller_walk", {"C_Yw": 0.01, "C_Nw": -0.004})
    assert get_effect(held.name) is held
    assert pickle.loads(pickle.dumps(held)).name == held.name
    x = 0.1 + 0.2  # a value Python writes with 17 digits comes back exactly
    assert split_name(get_effect(fixed(walk, (x, 0.0)).name).name)[1] == {"C_Yw": x, "C_Nw": 0.0}
    # a fixed effect in a box, and a box around a fixed effect, read back
    boxed = get_effect("propeller_walk@held(u=0.2:1.3,n_p=3:5)")
    assert split_name(get_effect(fixed(boxed, (0.01, 0.0)).name).name)[0] == boxed.name
    outer = get_effect(held.name + "@held(u=0.2:1.3)")
    assert outer.params == () and outer.name.endswith("@held(u=0.2:1.3)")
    for bad, message in (
        ("propeller_walk@fixed(C_Yw=a,C_Nw=0)", "is not a number"),
        ("propeller_walk@fixed(C_Xw=0.1)", "no parameter(s) C_Xw"),
        ("propeller_walk@fixed(C_Yw 0.1)", "expected name=value"),
        ("warp@fixed(C=1)", "unknown effect 'warp'"),
    ):
        with pytest.raises(KeyError, match=re.escape(message)):
            get_effect(bad)


def test_a_model_carrying_fixed_effects_simulates_as_with_the_effects_at_those_values():
    p = efd_parameters()
    free = shared_effects()
    values = [v for e in free for v in HELD.get(e.name, e.neutral())]
    with_values = with_effects(p, free, values)
    held = held_effects()
    carrying = Parameters(p.theta, p.ship, tuple((e.name, ()) for e in held))
    x = np.array([[1.0, 0.25, -2.0, 0.03, 0.4, 0.01]])
    u = np.tile([0.2, 9.0], (1, 300, 1))
    u[0, 100:, 0] = -0.3
    w = np.tile([2.0, 1.0], (1, 300, 1))
    a = simulate(x, u, w, with_values, effects=free)
    b = simulate(x, u, w, carrying, effects=held)
    # the very kernel of the effects held, with the held values in their rows: bit for bit
    assert kernel_effects(held) == free
    assert load_kernel(kernel_effects(held)) is load_kernel(free)
    np.testing.assert_array_equal(b, a)
    assert np.abs(b - simulate(x, u, w, p)).max() > 1e-2  # the held effects do act
    # a fit's vector and box do not see them; with_effects keeps them in the model
    assert full_vector(carrying, held).shape == (57,) and joint_box(held).n == 57
    walk = get_effect("propeller_walk")
    both = with_effects(carrying, (walk,), (0.02, 0.0))
    assert [n for n, _ in both.effects] == [*(e.name for e in held), "propeller_walk"]


def test_held_rows_go_where_the_held_effects_parameters_would_be():
    """Pointwise derivatives and accelerations of a model carrying held effects between free
    ones: the fit's rows (57 + the free effects' parameters) are those of the effects' kernel
    with the held values put in."""
    p = efd_parameters()
    free = shared_effects()
    values = np.array([v for e in free for v in HELD.get(e.name, e.neutral())])
    # hold every effect but the second, which stays free with the values of HELD
    k = len(free[0].params), len(free[1].params)
    model = (fixed(free[0], list(values[: k[0]])), free[1], *held_effects()[2:])
    rows = np.concatenate([p.vector(), values[k[0] : k[0] + k[1]]])[None, :]
    full = np.concatenate([p.vector(), values])[None, :]
    x = np.array([[1.0, 0.25, -2.0, 0.03, 0.4, 0.01], [0.0, -0.1, 3.0, 0.02, -1.0, -0.02]])
    u = np.array([[0.2, 9.0], [-0.3, -4.0]])
    w = np.array([[2.0, 1.0], [1.0, -2.0]])
    t = np.array([5.0, 50.0])
    np.testing.assert_array_equal(
        derivatives_rows(x, u, w, rows, model, t=t), derivatives_rows(x, u, w, full, free, t=t)
    )
    last = effect_accelerations_rows(x, u, w, rows, model, t=t)
    np.testing.assert_array_equal(last, effect_accelerations_rows(x, u, w, full, free, t=t))
    with pytest.raises(ValueError, match="rows must have shape"):
        derivatives_rows(x, u, w, full, model)
