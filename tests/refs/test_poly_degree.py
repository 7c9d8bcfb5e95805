"""Polynomial references of degree 3, 5 and 7 (``traj.degree``; the authors' PolyRef is degree 3)
against their definition: zero at both ends, the drawn end derivatives, the degree itself."""

from __future__ import annotations

import math

import pytest
import torch

from datt.configuration import compose, instantiate_option
from datt.refs import Poly
from datt.refs.poly import eval_pieces, quintic_zero_ends, zero_ends_fit

T_END_S = 10.0


@pytest.mark.parametrize("degree", [3, 5, 7])
def test_the_fit_is_zero_at_both_ends_with_the_given_derivatives(degree):
    """``zero_ends_fit``'s polynomial at random boundary derivatives: p(0) = p(h) = 0 and each
    derivative k = 1 .. m - 1 at each end is the value asked for (evaluated by Horner with
    derivatives, not by the solve)."""
    m = (degree + 1) // 2
    h = torch.tensor([2.0, 10.0], dtype=torch.float64)
    ends = torch.randn(2, 2 * (m - 1), 1, generator=torch.Generator().manual_seed(degree), dtype=torch.float64)
    coeffs = (zero_ends_fit(degree, h) @ ends).unsqueeze(1)  # [2, 1, degree + 1, 1]
    assert coeffs.shape[2] == degree + 1
    for i in range(2):
        knot_t = torch.tensor([[0.0, float(h[i])]], dtype=torch.float64)
        at = torch.tensor([0.0, float(h[i])], dtype=torch.float64)
        assert eval_pieces(knot_t, coeffs[i : i + 1], at).abs().max() < 1e-9
        for k in range(1, m):
            got = eval_pieces(knot_t, coeffs[i : i + 1], at, derivative=k)[0, :, 0]
            want = ends[i, 2 * (k - 1) : 2 * k, 0]  # (at 0, at h)
            assert torch.allclose(got, want, atol=1e-8), (degree, k)


def test_the_general_fit_at_degree_five_is_the_quintic_closed_form():
    h = torch.tensor([1.5, 4.0, 10.0], dtype=torch.float64)
    assert torch.allclose(zero_ends_fit(5, h), quintic_zero_ends(h), atol=1e-12)


@pytest.mark.parametrize("degree", [3, 5, 7])
def test_a_drawn_reference_is_of_its_degree_rests_at_the_origin_and_keeps_each_bound(degree):
    bounds = {1: 0.5, 2: 2.0, 3: 3.0}  # velocity, acceleration, jerk: distinct, so a swap shows
    family = Poly(degree=degree, vel_max_mps=0.5, acc_max_mps2=2.0, jerk_max_mps3=3.0, max_amplitude_m=1000.0)
    knot_t, coeffs = family.sample_pieces(64, torch.Generator().manual_seed(0), torch.zeros(1, dtype=torch.float64))
    assert coeffs.shape == (64, 1, degree + 1, 2)
    assert coeffs[:, 0, degree].abs().min() > 0  # the leading term is there (degree, not less)
    ends = torch.tensor([0.0, T_END_S], dtype=torch.float64)
    assert eval_pieces(knot_t, coeffs, ends).abs().max() < 1e-9
    for k in range(1, (degree + 1) // 2):  # each end derivative within its own bound, spanning it
        at_ends = eval_pieces(knot_t, coeffs, ends, derivative=k).abs().max()
        assert 0.5 * bounds[k] < at_ends <= bounds[k] + 1e-9, (degree, k)


def test_degree_five_draws_what_the_paper_texts_references_always_were():
    """The default degree draws the same references as before the option existed: the bank's
    poly references (and every result trained on them) do not move."""
    t = torch.arange(0, 501, dtype=torch.float32) * 0.02
    default, explicit = Poly(), Poly(degree=5)
    a = default.sample(8, t, torch.Generator().manual_seed(5))
    b = explicit.sample(8, t, torch.Generator().manual_seed(5))
    assert torch.equal(a, b)
    assert a.abs().amax() <= 1.5 + 1e-6  # the paper text's amplitude cap still applies


def test_the_authors_options_are_degree_three_without_a_cap():
    poly = instantiate_option(compose("train", ["traj=poly_authors"]), "traj")
    assert (poly.degree, poly.max_amplitude_m) == (3, 1000.0)
    mixed = compose("train", ["traj=mixed_authors"]).traj
    assert mixed.families.poly.degree == 3 and mixed.families.poly.max_amplitude_m == 1000.0
    assert set(mixed.families) == {"zigzag", "poly", "chained_poly"} and mixed.weights is None
    # a degree-3 reference reaches further than the capped degree-5 one (the authors' draws are uncapped)
    t = torch.arange(0, 501, dtype=torch.float64) * 0.02
    reach = poly.sample(500, t, torch.Generator().manual_seed(0))[..., :2].abs().amax()
    assert reach > 1.5 and math.isfinite(float(reach))
