"""``jaxtree modes``: the modes of the linearized small hinges (Eqs. 40-104) about a nominal
motion: the frequency table with labels and damping, a modes result file and a mode-shape plot."""

from __future__ import annotations

import pathlib

import jax.numpy as jnp
import numpy as np

from ..hybrid.linear import linearize
from ..io import mode_plots
from ..io.result_files import command_line, write_netcdf
from ..io.results import modes_dataset
from ..linear.linearize import structure
from ..linear.modes import ModalError, modes
from ..scene.appendages import scene_appendages
from .common import UserError, existing, hinges, open_scene, say, use_matplotlib, wrote


def cmd_modes(args) -> int:
    model = open_scene(args.scene)
    small = hinges(model, args.small, "--small")
    spin = np.zeros(3) if args.spin is None else np.asarray(args.spin, float)
    dtype = jnp.result_type(model.mass)
    apps = scene_appendages(model) if getattr(model, "appendages", ()) else ()
    lin = linearize(model, small, omega0=jnp.asarray(spin, dtype), appendages=apps)
    st = structure(lin.I, lin.J, lin.K)
    if args.damping is not None and args.damping < 0:
        raise UserError(f"--damping must be >= 0, got {args.damping}")
    try:
        md = modes(lin, damping=args.damping)
    except ModalError as e:
        raise UserError(f"modes of {model.name!r} with small hinges {list(small)}: {e}") from None
    out = pathlib.Path(args.out if args.out else f"{model.name or pathlib.Path(args.scene).stem}_modes.nc")
    ds = modes_dataset(
        model,
        md,
        small=small,
        hinges=lin.hinges,
        omega0=spin,
        attrs={"command": command_line(), "damping": args.damping, "structure": st.describe()},
    )
    existed = existing([out, args.plot if args.plot else out.with_suffix(".png")])
    write_netcdf(ds, out)
    f = np.asarray(md.frequencies)
    z = np.asarray(md.damping_ratios)
    what = (
        f"the small hinges {list(small)} ({', '.join(model.names[k] for k in small[:6])}{', ...' if len(small) > 6 else ''})"
        if small
        else "no hinge"
    )
    print(f"scene {model.name!r}: modes of {what}, nominal omega0 = {spin.tolist()} rad/s")
    if apps:
        names = ", ".join(f"{ap.name or i} ({ap.n_modes})" for i, ap in enumerate(apps))
        print(f"  and the finite-element appendages' held-interface modal coordinates: {names}")
    print(f"  {st.describe()}")
    print(f"{'mode':>5} {'sigma (rad/s)':>14} {'f (Hz)':>11} {'period (s)':>11} {'zeta':>8}  dominated by")
    for j in range(md.nu):
        period = 2 * np.pi / f[j] if f[j] > 0 else float("inf")
        label = md.labels[j] if md.labels else ""
        print(f"{j + 1:5d} {f[j]:14.6g} {f[j] / (2 * np.pi):11.5g} {period:11.5g} {z[j]:8.4f}  {label}")
    print(
        "  dominated by: each coordinate's share of the mode's participation sum_i |phi_i|^2 I_ii (its kinetic "
        "energy by the diagonal of I), largest first; + / - in phase / antiphase with the first"
    )
    written = [str(out)]
    if not args.no_plot:
        if use_matplotlib():
            png = args.plot if args.plot else str(out.with_suffix(".png"))
            mode_plots.plot_mode_shapes(model, ds, path=png, modes=list(range(min(args.show, md.nu))))
            written.append(png)
        else:
            say("matplotlib is not installed: no mode-shape plot (pip install 'jaxtree[plot]')")
    print(wrote(written, existed))
    return 0
