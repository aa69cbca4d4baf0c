"""The vehicle model: user input of Sec. II D of Likins (1972) as an equinox Module.

Physical parameters are JAX array leaves (differentiable, vmappable); the tree
(Defs. 4-5) and every structural choice (which hinges are prescribed, which
carry springs, which bodies are massless, which bodies feel external loads)
are static fields, fixed when the model is built, so that what a scene does
not need is never traced.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .topology import Topology


class State(NamedTuple):
    """Instantaneous state of Eq. (1): ``dcm`` is C of Def. 9 ({b^0} = C {i}); ``omega0`` in {b^0};
    ``gamma[k-1]`` and ``gamma_dot[k-1]`` are the angle and rate of hinge k."""

    dcm: jax.Array
    omega0: jax.Array
    gamma: jax.Array
    gamma_dot: jax.Array


class Prescription(eqx.Module):
    """Kinematically prescribed hinge angles ``gamma_j(t)`` (Sec. II B).

    Subclasses set `hinges` (static tuple of hinge indices 1..n) and implement
    ``__call__(t) -> angles`` of shape ``(len(hinges),)``; rates and accelerations
    are taken by forward-mode differentiation, so any JAX-differentiable
    function of time works.
    """

    hinges: eqx.AbstractVar[tuple[int, ...]]

    @abc.abstractmethod
    def __call__(self, t) -> jax.Array:
        """Angles of the prescribed hinges at time t, shape ``(len(hinges),)``."""

    def derivatives(self, t):
        """``(gamma, gamma_dot, gamma_ddot)`` of the prescribed hinges at time t."""
        t = jnp.asarray(t)
        first = lambda s: jax.jvp(self.__call__, (s,), (jnp.ones_like(s),))
        (g, gd), (_, gdd) = jax.jvp(first, (t,), (jnp.ones_like(t),))
        return g, gd, gdd


class SinePrescription(Prescription):
    """The scene format's ``sine`` form: ``gamma_j(t) = A_j sin(W_j t + P_j)``."""

    hinges: tuple[int, ...] = eqx.field(static=True)
    amplitude: jax.Array
    frequency: jax.Array
    phase: jax.Array

    def __call__(self, t):
        return self.amplitude * jnp.sin(self.frequency * t + self.phase)


class BodyLoads(eqx.Module):
    """External forces F^k and torques T^k (Defs. 19-20) on a static subset of bodies.

    ``__call__(t, state)`` returns ``(force, torque)``, each ``(len(bodies), 3)`` in
    the frames of the listed bodies: the force acts at the body's mass center and
    the torque is the moment about it. Bodies not listed feel nothing, and a model
    with no loads traces no load terms at all.
    """

    bodies: eqx.AbstractVar[tuple[int, ...]]

    @abc.abstractmethod
    def __call__(self, t, state: State) -> tuple[jax.Array, jax.Array]:
        """``(force, torque)``, each ``(len(bodies), 3)``, at time t and `state`."""


class FunctionLoads(BodyLoads):
    """Loads from a plain function ``fn(t, state) -> (force, torque)``; see :class:`BodyLoads`."""

    bodies: tuple[int, ...] = eqx.field(static=True)
    fn: Callable = eqx.field(static=True)

    def __call__(self, t, state):
        return self.fn(t, state)


class Model(eqx.Module):
    """A tree of n+1 rigid bodies joined by n revolute hinges (Likins 1972, Sec. II D).

    Array leaves (float, differentiable):

    - `mass` (n+1,), `inertia` (n+1, 3, 3) about each mass center in the body frame;
    - `axis` (n, 3) unit hinge axes g^k; `hinge_on_parent` (n, 3) = p^{N_k k};
      `hinge_on_body` (n, 3) = p^{k N_k} (Def. 13);
    - `stiffness`, `damping` (n,): spring-damper law ``tau_k = -k gamma_k - d gamma_dot_k``
      on the hinges listed in `sprung` (zero and unused elsewhere);
    - `initial`: the scene's initial :class:`State`.

    Static fields: `topology`, `joints` (joint kind per hinge), `sprung` (hinges
    whose spring law is traced), `massive` (bodies whose mass or inertia is not
    structurally zero), `prescription`, `loads`, and `method`, how Eq. (1) is solved:
    ``"dense"`` (its matrix assembled and factored, :mod:`jaxtree._src.equations.dynamics`),
    ``"articulated"`` (a blocked articulated-body recursion over the tree's substructures,
    :mod:`jaxtree._src.equations.articulated`: linear in n for deep chains, one level for a hub with
    appendages) or ``"auto"`` (a static rule on the topology and the backend,
    :func:`jaxtree._src.equations.articulated.resolve_method`), with `block_size` the most hinges per block
    of the articulated method (0: its default). All give the same accelerations to round-off.

    Laws a scene carries (Sec. II D inputs 7-8; all optional, None when absent): `law`, a hinge
    law ``tau(t, state, params)`` (e.g. :class:`~jaxtree.HingePD`), and `controller`, an
    :class:`~jaxtree.control.AbstractController` with internal states (e.g.
    :class:`~jaxtree.HingePID`), which :func:`jaxtree.simulate` adds to those it is given; and
    `orbit`, the :class:`~jaxtree.CircularOrbit` of the mass center (Eq. 2 with a central
    body), whose rate the scene's gravity-gradient load uses.

    Build models with :func:`jaxtree.build_model` or :func:`jaxtree.load_scene`,
    which validate the input before anything is traced.
    `appendages`: the finite-element appendages a scene declares (static records,
    :class:`~jaxtree._src.scene.appendages.AppendageSpec`), built by :func:`jaxtree.scene_appendages`
    for :func:`jaxtree.hybrid_model`; the full Eq. (1) leaves them out.
    """

    mass: jax.Array
    inertia: jax.Array
    axis: jax.Array
    hinge_on_parent: jax.Array
    hinge_on_body: jax.Array
    stiffness: jax.Array
    damping: jax.Array
    initial: State
    prescription: Prescription | None
    loads: BodyLoads | None
    topology: Topology = eqx.field(static=True)
    joints: tuple[str, ...] = eqx.field(static=True)
    sprung: tuple[int, ...] = eqx.field(static=True)
    massive: tuple[int, ...] = eqx.field(static=True)
    name: str = eqx.field(static=True, default="")
    method: str = eqx.field(static=True, default="auto")
    block_size: int = eqx.field(static=True, default=0)
    law: Any = None
    controller: Any = None
    orbit: Any = None
    appendages: tuple = eqx.field(static=True, default=())

    def __check_init__(self):
        if self.method not in ("auto", "dense", "articulated"):
            raise ValueError(f"Model: field 'method' must be 'auto', 'dense' or 'articulated', got {self.method!r}")
        if not isinstance(self.block_size, int) or self.block_size < 0:
            raise ValueError(f"Model: field 'block_size' must be an int >= 0, got {self.block_size!r}")

    @property
    def n(self) -> int:
        return self.topology.n

    @property
    def names(self) -> tuple[str, ...]:
        return self.topology.names

    @property
    def prescribed(self) -> tuple[int, ...]:
        """Indices (1..n) of the kinematically prescribed hinges."""
        return () if self.prescription is None else tuple(self.prescription.hinges)

    @property
    def inert(self) -> tuple[int, ...]:
        """Hinges (1..n) with nothing but massless bodies outboard: their rows and columns of
        Eq. (1) vanish, so they are left out of the unknowns and their accelerations are zero."""
        eps = self.topology.path_elements
        heavy = np.zeros(self.n + 1, dtype=bool)
        heavy[list(self.massive)] = True
        return tuple(s for s in range(1, self.n + 1) if not heavy[eps[s - 1].astype(bool)].any())

    @property
    def unknown_hinges(self) -> tuple[int, ...]:
        """Indices (1..n) of hinges whose angles are unknowns of Eq. (1)."""
        skip = set(self.prescribed) | set(self.inert)
        return tuple(k for k in range(1, self.n + 1) if k not in skip)

    def body_index(self, name_or_index) -> int:
        """Index of a body given its name (or the index itself)."""
        if isinstance(name_or_index, str):
            try:
                return self.names.index(name_or_index)
            except ValueError:
                raise KeyError(f"no body named {name_or_index!r}; bodies are {self.names}") from None
        k = int(name_or_index)
        if not 0 <= k <= self.n:
            raise IndexError(f"body index {k} outside 0..{self.n}")
        return k

    def with_method(self, method: str, block_size: int | None = None) -> Model:
        """A copy of the model that solves Eq. (1) by `method` (``"auto"``, ``"dense"`` or
        ``"articulated"``; see the class docstring). `block_size`: the most hinges per block of
        the articulated method (0: its default, :data:`jaxtree._src.equations.articulated.DEFAULT_BLOCK`)."""
        block_size = self.block_size if block_size is None else int(block_size)
        return dataclasses.replace(self, method=method, block_size=block_size)

    def with_loads(self, loads: BodyLoads | None) -> Model:
        """A copy of the model with other external loads (or none)."""
        return eqx.tree_at(lambda m: m.loads, self, loads, is_leaf=lambda x: x is None)

    def with_control(self, law=None, controller=None) -> Model:
        """A copy of the model that carries the hinge `law` and the `controller` (or none)."""
        return eqx.tree_at(lambda m: (m.law, m.controller), self, (law, controller), is_leaf=lambda x: x is None)

    def astype(self, dtype) -> Model:
        """All floating leaves cast to `dtype` (e.g. ``jnp.float32`` for GPU batches)."""
        return jax.tree_util.tree_map(lambda x: x.astype(dtype) if eqx.is_inexact_array(x) else x, self)
