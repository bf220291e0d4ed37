"""A closed form's corner and width fitted by output error (:mod:`sweep.diagnose.corners`).

The search is checked against a known optimum: the refit here is a test double that returns
a training J whose minimum lies at a corner and width of our choosing (the real refit is a
joint output-error fit, exercised by the diagnosis's own tests and benchmarks)."""

from __future__ import annotations

import math
from typing import Any

import pytest

from mmg import Effect, Parameters, efd_parameters
from mmg.shapes import groups_of, parse_form, shape_effect
from sweep.diagnose.corners import fit_numbers, grid_step
from sweep.identification.vector import effect_values, with_effects

FINE = 40
#: effective residuals of the refit's J (a small planted case's)
N_EFF = 840.0


def _refit_towards(corner: float, width: float | None, calls: list[str]) -> Any:
    """A refit whose J is smallest at ``corner`` (and ``width``): J = 1 + (c - corner)^2 +
    (log w - log width)^2, the coefficients moved to 0.1 each."""

    def refit(effect: Effect, p0: Parameters) -> tuple[float, Parameters]:
        calls.append(effect.name)
        args = parse_form(groups_of(effect)[0].form).args
        J = 1.0 + (args[0] - corner) ** 2
        if width is not None:
            J += (math.log(args[1]) - math.log(width)) ** 2
        return J, with_effects(p0, (effect,), [0.1] * len(effect.params))

    return refit


def test_a_steps_corner_and_width_move_to_where_the_refit_is_best() -> None:
    effect = shape_effect("S~alphaR[-3.35:3.1]:absstep(0.35,0.0621)*F_R")
    p0 = with_effects(efd_parameters(), (effect,), [0.01, -0.06])
    calls: list[str] = []
    fitted = fit_numbers(effect, p0, _refit_towards(0.40, 0.03, calls), FINE, N_EFF)
    assert fitted is not None
    corner, width = parse_form(groups_of(fitted.effect)[0].form).args
    step = grid_step(groups_of(effect)[0], FINE)
    assert abs(corner - 0.40) <= step / 8  # within the last round's step
    assert width == pytest.approx(0.0621 / 2, rel=1e-3)  # the nearest of the widths tried
    assert fitted.J_fitted < fitted.J_named
    assert fitted.count == 2  # a corner and a width
    assert fitted.start == [0.1, 0.1]
    assert len(set(calls)) == len(calls)  # no trial fitted twice


def test_a_hinges_corner_stays_inside_the_range_and_counts_one_number() -> None:
    effect = shape_effect("YN~beta[-1:1.2]:absup(0.5)")
    p0 = with_effects(efd_parameters(), (effect,), effect_values(efd_parameters(), (effect,)))
    fitted = fit_numbers(effect, p0, _refit_towards(5.0, None, []), FINE, N_EFF)
    assert fitted is not None
    (corner,) = parse_form(groups_of(fitted.effect)[0].form).args
    assert 0.5 < corner < 1.2  # moved towards the optimum, never past the range's larger side
    assert fitted.count == 1


def test_a_waves_period_and_phase_move_to_where_the_refit_is_best() -> None:
    """A wave named on the grid (period 40 s: the nearest of 2 x 400 s / k; phase pi / 6) over a
    400-s range moves to the refit's optimum (40.9 s, 0.3): its frequency within an eighth of
    the naming's spacing (half a cycle over the range), its phase at the middle of the range
    within an eighth of pi / 6; two numbers counted."""
    effect = shape_effect("x~t[5:405]:wave(40,0.523599)")
    p0 = with_effects(efd_parameters(), (effect,), [0.0, 0.01])

    t = [5.0 + 0.5 * k for k in range(801)]

    def refit(e: Effect, p: Parameters) -> tuple[float, Parameters]:
        """J of the wave against sin(2 pi t / 40.9 + 0.3) over the range: a misfit that, like a
        trajectory's, turns with the phase at every t."""
        T, phi = parse_form(groups_of(e)[0].form).args
        gap = [
            math.sin(2 * math.pi * z / T + phi) - math.sin(2 * math.pi * z / 40.9 + 0.3) for z in t
        ]
        return 1.0 + sum(d * d for d in gap) / len(t), with_effects(p, (e,), [0.1, 0.1])

    fitted = fit_numbers(effect, p0, refit, FINE, N_EFF)
    assert fitted is not None and fitted.count == 2
    T, phi = parse_form(groups_of(fitted.effect)[0].form).args
    assert abs(1.0 / T - 1.0 / 40.9) <= 0.5 / 400.0 / 8
    # the phase at the middle of the range (t = 205 s), which the period leaves in place
    mid = phi + 2 * math.pi * 205 / T - (0.3 + 2 * math.pi * 205 / 40.9)
    assert abs(math.remainder(mid, 2 * math.pi)) <= math.pi / 6 / 8


def test_forms_without_a_corner_are_left_alone() -> None:
    effect = shape_effect("X~U[0:0.4]:lin+N~beta[-1:1]:cos(2)")
    p0 = with_effects(efd_parameters(), (effect,), [0.0] * len(effect.params))
    assert fit_numbers(effect, p0, _refit_towards(0.0, None, []), FINE, N_EFF) is None


def test_numbers_that_do_not_pay_for_themselves_in_bic_stay_as_named() -> None:
    """A corner 0.05 away from the optimum lowers J by 0.25 %: less than the BIC's price of
    two more parameters over 840 residuals; the named form is kept, nothing counted."""
    effect = shape_effect("S~alphaR[-3.35:3.1]:absstep(0.35,0.0621)*F_R")
    p0 = with_effects(efd_parameters(), (effect,), [0.01, -0.06])

    def refit(e: Effect, p: Parameters) -> tuple[float, Parameters]:
        c = parse_form(groups_of(e)[0].form).args[0]
        return 1.0 + (c - 0.40) ** 2, with_effects(p, (e,), [0.2, 0.2])

    fitted = fit_numbers(effect, p0, refit, FINE, N_EFF)
    assert fitted is not None
    assert fitted.effect.name == effect.name and fitted.count == 0
    assert fitted.J_fitted == fitted.J_named
    assert fitted.start == [0.2, 0.2]  # the named form's own fit
