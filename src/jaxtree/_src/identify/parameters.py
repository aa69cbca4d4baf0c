"""The parameters of a fit: named groups of model quantities, each fitted as itself or as its
logarithm, and the one traced map from the fitted vector ``theta`` to a model."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SceneError, SceneKeyError, SceneTypeError
from ..vehicle.model import Model
from . import quantities as qty


@dataclasses.dataclass(frozen=True)
class Parameters:
    """`names` of the parameters; `quantities[p]` the quantities parameter p sets; `log[p]`
    whether theta[p] is the logarithm of the value. Static: hashable, fixed before tracing."""

    names: tuple[str, ...]
    quantities: tuple[tuple[qty.Quantity, ...], ...]
    log: tuple[bool, ...]

    @property
    def size(self) -> int:
        return len(self.names)

    def to_theta(self, values) -> jax.Array:
        """Physical values (..., P) to the fitted coordinates."""
        v = jnp.asarray(values)
        return jnp.where(np.asarray(self.log), jnp.log(jnp.where(np.asarray(self.log), v, 1.0)), v)

    def to_values(self, theta) -> jax.Array:
        """The fitted coordinates (..., P) to physical values."""
        return jnp.where(np.asarray(self.log), jnp.exp(theta), theta)

    def value_rates(self, theta) -> jax.Array:
        """d value / d theta, elementwise (first-order propagation of the covariance)."""
        return jnp.where(np.asarray(self.log), jnp.exp(theta), 1.0)

    def apply(self, model: Model, theta) -> Model:
        """`model` with every quantity set from `theta` (traced; one scatter per leaf touched)."""
        values = self.to_values(theta)
        dynamic, static = eqx.partition(model, eqx.is_inexact_array)
        leaves, tdef = jax.tree_util.tree_flatten(dynamic)  # the inexact array leaves, in quantities' order
        touched: dict[int, tuple[list, list]] = {}
        for p, group in enumerate(self.quantities):
            for q in group:
                places, which = touched.setdefault(q.leaf, ([], []))
                for idx in (q.index, q.mirror):
                    if idx is not None:
                        places.append(idx)
                        which.append(p)
        for leaf, (places, which) in touched.items():
            x = leaves[leaf]
            new = values[np.asarray(which)].astype(x.dtype)
            if x.ndim == 0:
                leaves[leaf] = new[0]
            else:
                leaves[leaf] = x.at[tuple(np.asarray(c) for c in zip(*places))].set(new)
        return eqx.combine(jax.tree_util.tree_unflatten(tdef, leaves), static)


def parameters(model: Model, free, log: Mapping | None = None) -> Parameters:
    """Resolve `free` (a list of quantity names, each its own parameter, or a dict ``parameter
    name -> list of quantities set together``) in `model`; `log` overrides, by parameter name,
    whether a parameter is fitted as its logarithm (default: when all its quantities must be
    positive)."""
    if isinstance(free, str):
        free = [free]
    if isinstance(free, Mapping):
        groups = {}
        for name, qs in free.items():
            if not isinstance(name, str):
                raise SceneTypeError(f"identify: free: parameter names are strings, got {name!r}")
            qs = [qs] if isinstance(qs, str) else list(qs)
            if not qs:
                raise SceneError(f"identify: free[{name!r}] names no quantity")
            groups[name] = qs
    else:
        try:
            names = list(free)
        except TypeError:
            raise SceneTypeError(f"identify: free must be a list of quantities or a dict, got {free!r}") from None
        groups = {}
        for name in names:
            if name in groups:
                raise SceneError(f"identify: free: parameter {name!r} is named twice")
            groups[name] = [name]
    if not groups:
        raise SceneError("identify: free names no parameter")
    seen: dict[tuple, str] = {}
    resolved, logs = [], []
    log = dict(log or {})
    unknown = set(log) - set(groups)
    if unknown:
        raise SceneKeyError(f"identify: log: no parameter named {sorted(unknown)[0]!r}; parameters are {list(groups)}")
    for pname, qs in groups.items():
        group = []
        for qname in qs:
            q = qty.resolve(model, qname)
            for idx in (q.index, q.mirror):
                if idx is None:
                    continue
                key = (q.leaf, idx)
                if key in seen:
                    raise SceneError(
                        f"identify: free: quantity {qname!r} (parameter {pname!r}) is already set by {seen[key]!r}"
                    )
                seen[key] = f"{q.name} in parameter {pname}" if len(groups[pname]) > 1 else q.name
            group.append(q)
        positive = all(q.positive for q in group)
        as_log = bool(log.get(pname, positive))
        resolved.append(tuple(group))
        logs.append(as_log)
    return Parameters(tuple(groups), tuple(resolved), tuple(logs))


def start_values(model: Model, params: Parameters, start, members: int | None) -> np.ndarray:
    """Starting physical values (P,) or (members, P): `start` by parameter name where given, else
    the mean of the model's values of each parameter's quantities; checked (finite; positive
    for a logarithm)."""
    start = dict(start or {})
    unknown = set(start) - set(params.names)
    if unknown:
        raise SceneKeyError(
            f"identify: start: no parameter named {sorted(unknown)[0]!r}; parameters are {list(params.names)}"
        )
    shape = () if members is None else (members,)
    columns = []
    for name, group in zip(params.names, params.quantities):
        if name in start:
            try:
                v = np.asarray(start[name], dtype=float)
            except (TypeError, ValueError):
                raise SceneTypeError(f"identify: start[{name!r}] must be a number, got {start[name]!r}") from None
            if v.shape not in ((), shape):
                raise SceneError(
                    f"identify: start[{name!r}]: a number{' or one per member' if members else ''}, got shape {v.shape}"
                )
            v = np.broadcast_to(v, shape)
        else:
            v = np.full(shape, np.mean([qty.value(model, q) for q in group]))
        columns.append(v)
    values = np.stack(columns, -1)
    for p, name in enumerate(params.names):
        col = values[..., p]
        if not np.all(np.isfinite(col)):
            raise SceneError(f"identify: parameter {name!r}: the start is not finite")
        if params.log[p] and np.any(col <= 0):
            raise SceneError(
                f"identify: parameter {name!r} is fitted as a logarithm but starts at {float(np.min(col)):g}; "
                f"give a positive start, or log={{{name!r}: False}}"
            )
    return values


def with_quantities(model: Model, values: Mapping) -> Model:
    """`model` with named quantities set: ``values`` a dict ``quantity -> number`` in the names of
    :func:`jaxtree.identify` (``"wingp_1.stiffness"``, ``"hub.inertia[0,1]"`` (both entries),
    ``"initial.omega0[2]"`` ...). The numbers may be traced (differentiable, vmappable)."""
    if not isinstance(values, Mapping):
        raise SceneTypeError(f"with_quantities: values must be a dict quantity -> number, got {type(values).__name__}")
    names = list(values)
    p = parameters(model, names, log={n: False for n in names})
    return p.apply(model, jnp.stack([jnp.asarray(values[n], jnp.result_type(model.mass)) for n in names]))
