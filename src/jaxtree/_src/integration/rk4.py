"""The classical fourth-order Runge-Kutta method as a diffrax solver, for fixed steps as
fixed-step engines use it (a peer's setting in the benchmarks)."""

from __future__ import annotations

import typing
from collections.abc import Callable

import diffrax as dfx
import numpy as np


class RK4(dfx.AbstractERK):
    """The classical fourth-order Runge-Kutta method, for fixed steps
    (``stepsize_controller=diffrax.ConstantStepSize(), dt0=h``), as fixed-step engines
    (MuJoCo's ``RK4``, Basilisk's ``svIntegratorRK4``) use it. It has no embedded error
    estimate (its error weights are zero): an adaptive controller would accept every step."""

    tableau: typing.ClassVar[dfx.ButcherTableau] = dfx.ButcherTableau(
        c=np.array([0.5, 0.5, 1.0]),
        b_sol=np.array([1 / 6, 1 / 3, 1 / 3, 1 / 6]),
        b_error=np.zeros(4),
        a_lower=(np.array([0.5]), np.array([0.0, 0.5]), np.array([0.0, 0.0, 1.0])),
    )
    interpolation_cls: typing.ClassVar[Callable[..., dfx.ThirdOrderHermitePolynomialInterpolation]] = (
        dfx.ThirdOrderHermitePolynomialInterpolation.from_k
    )

    def order(self, terms):
        return 4
