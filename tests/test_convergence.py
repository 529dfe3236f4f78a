"""Roache's grid convergence index (``shoulder_fem.io.convergence``) against hand calculations.

phi(h) = 2 + 0.5 h^p on h = 1, 1.5, 2.5 (unequal ratios, as the shoulder's levels): the
apparent order is p, the extrapolated value 2 and GCI_fine = 1.25 |e21/phi1| / (1.5^p - 1)
(Celik et al. 2008, eqs. 3-5); at p = 2: e21 = 0.625, phi1 = 2.5, so GCI_fine = 1.25 x 0.25 /
1.25 = 0.25. Differences that change sign are oscillatory; differences that grow as the mesh is
refined are no convergence, unless the last refinement changed the value by 1 % or less
(settled: a difference at the solver's tolerance has no trend).
"""

from __future__ import annotations

import pytest

from shoulder_fem.io.convergence import gci

H = (1.0, 1.5, 2.5)


@pytest.mark.parametrize("p", [1.0, 2.0, 3.3])
def test_a_power_law_gives_its_order_and_limit(p):
    phi = tuple(2.0 + 0.5 * h**p for h in H)
    result = gci(H, phi)
    assert result.kind == "monotone" and result.order == pytest.approx(p, rel=1e-9)
    assert result.extrapolated == pytest.approx(2.0, rel=1e-9)
    e21 = phi[1] - phi[0]
    assert result.gci_fine == pytest.approx(1.25 * abs(e21 / phi[0]) / (1.5**p - 1), rel=1e-9)


def test_the_hand_calculated_gci_and_the_verdict():
    result = gci(H, (2.5, 3.125, 5.125))  # 2 + 0.5 h^2
    assert result.gci_fine == pytest.approx(0.25, rel=1e-12)
    assert result.verdict == "converging"  # 25 % > the 5 % of "converged"
    fine = gci(H, tuple(2.0 + 1e-3 * h**2 for h in H))
    assert fine.verdict == "converged" and fine.gci_fine < 0.05


def test_oscillating_and_growing_differences_are_not_convergence():
    assert gci(H, (1.0, 1.2, 0.9)).verdict == "oscillatory"
    # an oscillation whose last step is 0.1 % (below SETTLED_CHANGE): settled, not a trend
    settled = gci(H, (1.0, 1.001, 0.8))
    assert settled.kind == "oscillatory" and settled.verdict == "settled"
    growing = gci(H, (1.0, 1.1, 1.15))  # e21 = 0.1 > e32 = 0.05: R = 2
    assert growing.verdict == "diverging" and growing.ratio == pytest.approx(2.0)
    assert growing.gci_fine is None and growing.relative_change == pytest.approx(0.1)


def test_sizes_out_of_order_are_refused():
    with pytest.raises(ValueError, match="must increase from the finest"):
        gci((2.0, 1.5, 1.0), (1.0, 1.0, 1.0))
