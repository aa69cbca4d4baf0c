"""``jaxtree identify SCENE RECORD --free ... --sigma ...``: the command-line verb of
:func:`jaxtree.identify`. Prints the estimates with their standard errors, the correlations
and the parameters the record cannot tell apart; writes a residual plot and, with ``--out``, the
estimates as JSON."""

from __future__ import annotations

import json
import pathlib
import time
import warnings

import numpy as np

from ..errors import SceneError
from .fit import ConvergenceWarning, IdentifiabilityWarning, identify
from .record import load_record, plot_residuals

DESCRIPTION = (
    "Estimate named parameters of a scene from a record of sensor readings (a CSV of sensor columns, or a "
    "result file of 'jaxtree simulate' read by the named sensors) by Levenberg-Marquardt through the simulation; "
    "print the estimates with standard errors and correlations, write a residual plot."
)


def add_arguments(p) -> None:
    p.add_argument("scene", metavar="SCENE", help="scene JSON file or a bundled scene name: the model fitted")
    p.add_argument(
        "record", metavar="RECORD", help="CSV with a 'time' column and sensor columns, or a jaxtree result file (.nc)"
    )
    p.add_argument(
        "--free",
        action="append",
        required=True,
        metavar="PARAM",
        help="a quantity ('wingp_1.stiffness', 'hub.inertia[1,1]', 'initial.omega0[2]') or NAME=Q1,Q2,... (quantities "
        "set together); repeat for more",
    )
    p.add_argument(
        "--sigma",
        action="append",
        required=True,
        metavar="SENSOR=SD",
        help="a sensor of the record and its noise standard deviation ('hub.omega=2e-6', 'hub.omega=1e-6,1e-6,2e-6'); "
        "repeat for more; only these sensors are fitted",
    )
    p.add_argument(
        "--start", action="append", default=[], metavar="PARAM=VALUE", help="a starting value (default: the scene's)"
    )
    p.add_argument(
        "--linear", action="append", default=[], metavar="PARAM", help="fit PARAM as itself, not its logarithm"
    )
    p.add_argument("--rtol", type=float, default=1e-8, help="the simulation's relative tolerance (default 1e-8)")
    p.add_argument("--atol", type=float, default=1e-8, help="the simulation's absolute tolerance (default 1e-8)")
    p.add_argument("--max-steps", type=int, default=100, help="most simulations of the fit (default 100)")
    p.add_argument("--progress", action="store_true", help="print each simulation's chi-square")
    p.add_argument("--plot", metavar="PNG", help="residual plot (default: RECORD's name with _residuals.png)")
    p.add_argument("--no-plot", action="store_true", help="write no plot")
    p.add_argument("--out", "-o", metavar="JSON", help="also write the estimates, standard errors and correlations")


def _pairs(items, option, convert):
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise SceneError(f"{option} {item!r}: expected NAME=VALUE")
        try:
            out[key.strip()] = convert(value)
        except ValueError:
            raise SceneError(f"{option} {item!r}: {value!r} is not a number or a list of numbers") from None
    return out


def _numbers(text):
    parts = [float(x) for x in text.split(",")]
    return parts[0] if len(parts) == 1 else parts


def _free(items):
    groups: dict[str, list[str]] = {}
    for item in items:
        name, sep, quantities = item.partition("=")
        qs = [q.strip() for q in quantities.split(",")] if sep else [item.strip()]
        key = name.strip() if sep else item.strip()
        if key in groups:
            raise SceneError(f"--free: parameter {key!r} is named twice")
        groups[key] = qs
    return groups


def run(args, model, matplotlib_ok: bool) -> int:
    """Run the verb on parsed `args` and a loaded `model`; raises SceneError for a user's mistake."""
    sigma = _pairs(args.sigma, "--sigma", _numbers)
    start = _pairs(args.start, "--start", float)
    free = _free(args.free)
    times, data = load_record(args.record, model, list(sigma))
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        warnings.simplefilter("always", IdentifiabilityWarning)
        fit = identify(
            model,
            free,
            times,
            data,
            sigma,
            start=start,
            rtol=args.rtol,
            atol=args.atol,
            max_steps=args.max_steps,
            log={name: False for name in args.linear},
            progress=args.progress,
            warn=True,
        )
    wall = time.perf_counter() - t0
    print(
        f"jaxtree identify: scene {model.name!r}, record {args.record} ({len(times)} samples, "
        f"{', '.join(data)}), {len(fit.names)} parameters; {fit.steps} simulations in {wall:.1f} s"
    )
    print(fit.table())
    if len(fit.names) > 1:
        print("correlations:")
        width = max(len(n) for n in fit.names)
        for i, n in enumerate(fit.names):
            print(f"  {n:{width}s} " + " ".join(f"{c:+.3f}" for c in np.asarray(fit.correlation)[i]))
    for w in caught:
        print(f"jaxtree identify: warning: {w.message}")
    written = []
    if not args.no_plot and matplotlib_ok:
        plot = args.plot or str(pathlib.Path(args.record).with_suffix("")) + "_residuals.png"
        plot_residuals(fit, times, plot)
        written.append(plot)
    if args.out:
        from ..atomic import atomic_write

        doc = {
            "scene": model.name,
            "record": str(args.record),
            "values": fit.values,
            "stderr": fit.stderr,
            "correlation": np.asarray(fit.correlation).tolist(),
            "names": list(fit.names),
            "steps": fit.steps,
            "converged": fit.converged,
            "reason": fit.reason,
            "chi2": fit.chi2,
            "dof": fit.dof,
            "unidentifiable": list(fit.unidentifiable),
        }
        with atomic_write(args.out, "w") as fh:
            json.dump(doc, fh, indent=1)
        written.append(args.out)
    if written:
        print(f"wrote {', '.join(written)}")
    return 0 if fit.converged else 1
