"""The configuration of a chunked run (:func:`chunked_config`) and its checks.

A run of :func:`~jaxtree._src.campaigns.chunked.simulate_to_file` is described by plain values
(numbers, text, lists): the save grid, the parts, the solver by class name (:func:`solver_named`;
``"auto"`` chosen here for Eq. (1), by the hybrid runner for the hybrid equations), the
tolerances and, for a hybrid run, the hinges in modal coordinates (:func:`parse_hinges`) and the
modal options. The configuration is stored in every part (``io/results.run_attrs``), and a
resumed run must have the same one. :class:`ChunkedRunError` names the option at fault.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import diffrax
import jax.numpy as jnp
import numpy as np

from ..integration.autosolver import choose_solver
from ..integration.core import default_tolerance
from ..integration.radau import Radau5
from ..integration.save_grid import save_points
from ..linear.linearize import resolve_hinges
from ..vehicle.model import Model


class ChunkedRunError(ValueError):
    """A configuration that cannot run, or a resume that does not fit the parts on disk:
    `option` names the argument at fault (``"resume"``, ``"hybrid_small"``, ...; two joined by
    "/" where either may be), `reason` says what is wrong."""

    def __init__(self, option: str, reason: str):
        super().__init__(f"{option}: {reason}")
        self.option, self.reason = option, reason


def solver_named(name: str):
    """A new solver of the class `name` (``"Radau5"`` for jaxtree's :class:`~jaxtree.Radau5`,
    else a diffrax solver class such as ``"Dopri8"``)."""
    return Radau5() if name == "Radau5" else getattr(diffrax, name)()


def parse_hinges(model: Model, spec) -> tuple[int, ...]:
    """The hinges that `spec` names, ascending: ``"all"`` (every hinge that is neither
    prescribed nor inert), text of comma-separated indices 1..n, body names and ranges ``a-b``,
    or a sequence of indices and names. Raises ``ValueError`` saying what is wrong."""
    if isinstance(spec, str) and spec.strip() == "none":
        return ()
    if isinstance(spec, str) and spec.strip() == "all":
        if not model.unknown_hinges:
            raise ValueError("the scene has no hinge that can be small")
        return tuple(model.unknown_hinges)
    if isinstance(spec, (int, np.integer)):
        spec = [spec]
    items: list[Any] = []
    for part in [p.strip() for p in spec.split(",")] if isinstance(spec, str) else list(spec):
        if isinstance(part, str) and "-" in part and all(s.strip().isdigit() for s in part.split("-", 1)):
            a, b = (int(s) for s in part.split("-", 1))
            items += list(range(a, b + 1))
        elif isinstance(part, str) and part.isdigit():
            items.append(int(part))
        elif part != "":
            items.append(part)
    if not items:
        raise ValueError("no hinge given")
    try:
        return resolve_hinges(model, items)
    except (ValueError, KeyError, TypeError) as e:
        msg = str(e.args[0]) if e.args else str(e)
        raise ValueError(msg.removeprefix("linearize: ")) from None


def chunked_config(
    model: Model,
    t1: float,
    *,
    t0: float = 0.0,
    points: int | None = None,
    chunks: int = 10,
    solver: str = "auto",
    rtol: float | None = None,
    atol: float | None = None,
    attitude: str = "quaternion",
    max_steps: int = 200_000,
    hybrid_small: str | Sequence[int | str] | None = None,
    modes: int | str | None = None,
    modes_tol: float | None = None,
    cutoff: float | None = None,
    spin: Sequence[float] | None = None,
    modal_damping: float | None = None,
) -> dict:
    """The configuration of a run of :func:`simulate_to_file`, as stored in each part.

    `points` evenly spaced save times from `t0` to `t1` (default: 20 per period of the fastest
    sprung hinge that still rings, at least 101) in `chunks` parts; `solver` a class name of
    diffrax or ``"Radau5"``, or ``"auto"`` (:func:`jaxtree.choose_solver` picks one for the scene);
    `rtol`, `atol` default to the dtype's (1e-9 in float64); `max_steps` is the step limit of
    each part. `hybrid_small` (text such as ``"1-4"`` or ``"all"``, see :func:`parse_hinges`, or a
    sequence of hinges) integrates the hybrid-coordinate equations with those hinges in modal
    coordinates: `modes` per substructure (a count, or ``"auto"``: the fewest whose neglected
    share is at most `modes_tol`, default 0.01; default all), up to the frequency `cutoff`,
    about the nominal spin `spin` (default the initial omega0) with `modal_damping`.
    """
    if not t1 > t0:
        raise ChunkedRunError("t1", f"{t1:g} is not after t0 = {t0:g}: a chunked run integrates forward in time")
    hybrid_options = dict(modes=modes, modes_tol=modes_tol, cutoff=cutoff, spin=spin, modal_damping=modal_damping)
    given = [k for k, v in hybrid_options.items() if v is not None]
    if hybrid_small is None and given:
        raise ChunkedRunError(given[0], "needs hybrid_small (the hinges in modal coordinates)")
    if modes_tol is not None and modes != "auto":
        raise ChunkedRunError("modes_tol", 'needs modes="auto"')
    tol = default_tolerance(jnp.result_type(model.mass))
    rtol, atol = rtol or tol, atol or tol
    why = "given"
    if solver == "auto" and hybrid_small is None:  # a hybrid run chooses on its own equations (PartRunner)
        _, choice = choose_solver(model, t1, t0=t0, rtol=rtol, atol=atol)
        solver, why = choice.name, f"auto: {choice.reason}"
    cfg: dict[str, Any] = {
        "t0": float(t0),
        "t1": float(t1),
        "points": int(save_points(model, float(t1 - t0))[0] if points is None else points),
        "chunks": int(chunks),
        "solver": solver,
        "solver_choice": why,
        "rtol": float(rtol),
        "atol": float(atol),
        "attitude": attitude,
        "max_steps": int(max_steps),
    }
    if hybrid_small is not None:
        cfg.update(
            hybrid_small=hybrid_small if isinstance(hybrid_small, str) else ",".join(map(str, hybrid_small)),
            n_modes=None if modes is None else "auto" if modes == "auto" else int(modes),
            cutoff=None if cutoff is None else float(cutoff),
            modal_damping=None if modal_damping is None else float(modal_damping),
            spin=list(map(float, spin if spin is not None else model.initial.omega0)),
        )
        if modes == "auto":
            cfg["modes_tol"] = 1e-2 if modes_tol is None else float(modes_tol)
    return cfg
