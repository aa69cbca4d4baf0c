"""The conditioning of Eq. (1).

:func:`condition` gives the condition number of the coefficient matrix of Eq. (1) (Defs. 38-40)
in its unknowns (omega0 and the hinges that are neither prescribed nor inert, Sec. II B) and the
direction of its eigenvalue nearest zero, named by hinges: where the matrix is nearly singular
(gimbal lock: two hinge axes aligned through massless gimbal frames) that is the combination of
rates that moves no mass. float64 keeps about ``16 - log10(cond)`` digits of the accelerations.

:func:`jaxtree.check_scene` (:mod:`jaxtree._src.scene.check`) prints it for a scene. The helpers
it shares with the diagnosis of a failed solve (:func:`jaxtree._src.equations.forward.diagnose`)
and ``simulate``'s failure reports are here too: :func:`matrix_condition`, :func:`unknown_rows`,
:func:`unknown_labels`, :func:`null_direction_text` and :data:`SINGULAR_CONDITION`.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..vehicle.model import Model, State
from .assembly import rotational_equations

# A condition number of Eq. (1)'s matrix above this is reported as singular (float64 keeps
# about four digits of the accelerations there).
SINGULAR_CONDITION = 1e12


def matrix_condition(model, A):
    """Condition number of the Eq. (1) matrix `A` with the prescribed rows and columns removed,
    and its eigenvector of the eigenvalue nearest zero (the near-null direction when singular)."""
    u = unknown_rows(model)
    ev, V = jnp.linalg.eigh(A[np.ix_(u, u)])
    i = jnp.argmin(jnp.abs(ev))
    return jnp.max(jnp.abs(ev)) / jnp.abs(ev[i]), V[:, i]


def unknown_rows(model):
    """Rows of Eq. (1) that are unknowns: omega0 and the hinges that are not prescribed or inert."""
    return np.concatenate([np.arange(3), np.asarray(model.unknown_hinges, dtype=np.int64) + 2])


def unknown_labels(model) -> tuple[str, ...]:
    """Labels of the unknown rows of Eq. (1), for messages: ``omega0x``..., ``hinge k (name)``."""
    return tuple("omega0" + "xyz"[i] if i < 3 else f"hinge {i - 2} ({model.names[i - 2]})" for i in unknown_rows(model))


def null_direction_text(v, labels) -> str:
    """Describe the near-null direction `v` of a singular Eq. (1) matrix by its large entries."""
    v = np.asarray(v, dtype=float)
    big = np.flatnonzero(np.abs(v) >= 0.25 * np.abs(v).max())
    parts = ", ".join(f"{labels[i]} {v[i]:+.3f}" for i in big)
    return (
        f"its near-null direction: {parts}. Rates in that direction move the vehicle alike (for a "
        f"gimbal: gimbal lock, two axes aligned)."
    )


# Above this condition number the summary warns that digits are being lost (float64 keeps
# about 8 of its 16 digits there).
POOR_CONDITION = 1e8


class Condition(eqx.Module):
    """Result of :func:`condition`.

    - `number`: ``max |lambda| / min |lambda|`` of the Eq. (1) matrix in its unknowns (the
      2-norm condition number of the symmetric positive definite matrix);
    - `direction` (3 + len(model.unknown_hinges),): unit eigenvector of the eigenvalue nearest
      zero, entries ordered as `labels` (``omega0x``, ``omega0y``, ``omega0z``, then
      ``hinge k (name)`` for the unknown hinges);
    - `labels` (static): the names of the entries of `direction`.
    """

    number: jax.Array
    direction: jax.Array
    labels: tuple[str, ...] = eqx.field(static=True)

    @property
    def singular(self) -> bool:
        """True when the matrix is singular to float64 working accuracy (the threshold at which
        :func:`jaxtree.simulate` diagnoses a failure as a singular Eq. (1))."""
        c = float(self.number)
        return not np.isfinite(c) or c > SINGULAR_CONDITION

    def named_direction(self, threshold: float = 0.25) -> list[tuple[str, float]]:
        """The entries of `direction` of at least `threshold` times its largest, as
        ``(label, value)`` pairs, the largest first; the sign makes the largest positive."""
        v = np.asarray(self.direction, dtype=float)
        if not np.all(np.isfinite(v)) or not np.any(v):
            return []
        v = v * np.sign(v[np.argmax(np.abs(v))])
        big = np.flatnonzero(np.abs(v) >= threshold * np.abs(v).max())
        big = big[np.argsort(-np.abs(v[big]), kind="stable")]
        return [(self.labels[i], float(v[i])) for i in big]

    def describe(self) -> str:
        """One line: the condition number, the digits it leaves, and the near-null direction."""
        c = float(self.number)
        parts = ", ".join(f"{name} {value:+.3f}" for name, value in self.named_direction())
        if not np.isfinite(c):
            return f"condition number of Eq. (1): infinite (singular matrix); near-null direction: {parts}"
        digits = max(0.0, 16.0 - np.log10(max(c, 1.0)))
        text = f"condition number of Eq. (1): {c:.3g} " + (
            "(singular to float64 working accuracy)" if self.singular else f"(float64 keeps about {digits:.0f} digits)"
        )
        return text + f"; direction of its smallest eigenvalue: {parts}"

    def __str__(self) -> str:
        return self.describe()


@eqx.filter_jit
def _condition_core(model: Model, state: State, t):
    gamma = state.gamma
    if model.prescription is not None:
        # the matrix depends on the angles of prescribed hinges: take them from the prescription
        idx = np.asarray(model.prescription.hinges, dtype=np.int64) - 1
        gamma = jnp.asarray(gamma).at[idx].set(jnp.asarray(model.prescription(t), jnp.result_type(gamma)))
    A, _ = rotational_equations(model, state._replace(gamma=gamma), t)
    return matrix_condition(model, A)


def condition(model: Model, state: State | None = None, t=0.0) -> Condition:
    """Condition number of Eq. (1) at `state` (default ``model.initial``) and time `t`, and the
    direction of its smallest eigenvalue named by hinges (:class:`Condition`).

    The matrix of Defs. 38-40 is restricted to the unknowns: omega0 and the hinges that are not
    prescribed (their angles at time `t` come from the prescription) or inert (nothing but
    massless bodies outboard). Only the hinge angles enter the matrix. Pure: the result is a
    pytree (jit and vmap it over states or model parameters).
    """
    state = model.initial if state is None else state
    if not isinstance(state, State):
        raise TypeError(f"condition: state must be a jaxtree.State, got {type(state).__name__}")
    number, direction = _condition_core(model, state, jnp.asarray(t, jnp.result_type(model.mass)))
    return Condition(number, direction, unknown_labels(model))
