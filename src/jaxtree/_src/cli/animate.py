"""``jaxtree animate`` and ``jaxtree plot``: a result file (a simulation, or a modes result) as an
HTML page animating it, or as its plots."""

from __future__ import annotations

import pathlib

import numpy as np

from ..io import history_plots, mode_plots
from .common import UserError, existing, model_of, open_result, use_matplotlib, wrote


def _viewer():
    try:
        from ..io import viewer  # looked up when used: an installation may lack it (a test stands one in)
    except ImportError:
        raise UserError("the 3D viewer (jaxtree.write_animation) is not available in this installation") from None
    return viewer


def cmd_animate(args) -> int:
    existed = existing([args.out])
    ds = open_result(args.result)
    model = model_of(ds, args.result)
    viewer = _viewer()
    kind = ds.attrs.get("kind")
    title = args.title
    if kind == "modes":
        nu = ds.sizes["mode"]
        k = 1 if args.mode is None else args.mode
        if not 1 <= k <= nu:
            raise UserError(f"--mode {k}: the result has modes 1..{nu}")
        shape = np.asarray(ds["hinge_shape"].values[:, k - 1], float)
        freq = float(ds["frequency"].values[k - 1])
        if title is None:
            label = str(ds["mode_label"].values[k - 1])
            title = f"{model.name}: mode {k}, {freq:.4g} rad/s ({freq / (2 * np.pi):.4g} Hz)" + (
                f", {label}" if label else ""
            )
        viewer.write_mode_animation(
            args.out,
            model,
            shape,
            freq,
            gamma=np.asarray(ds["gamma_nominal"].values, float),
            amplitude=args.amplitude,
            title=title,
        )
    else:
        if args.mode is not None or args.amplitude is not None:
            raise UserError(
                f"--mode and --amplitude apply to a modes result (jaxtree modes), {args.result} is a simulation"
            )
        if title is None:
            title = f"{model.name}: t = {float(ds['time'][0]):g} .. {float(ds['time'][-1]):g} s" + (
                "" if int(ds.attrs.get("complete", 1)) else " (partial run)"
            )
        viewer.write_animation(
            args.out,
            model,
            np.asarray(ds["time"].values),
            np.asarray(ds["dcm"].values),
            np.asarray(ds["gamma"].values),
            title=title,
            appendages=_output_nodes(ds, args.scale),
        )
    print(wrote([args.out], existed))
    return 0


def _output_nodes(ds, scale: float) -> list[dict]:
    """The finite-element appendages' output nodes of a simulation result, for the viewer: each a
    point on its body, displaced by `scale` times its translation."""
    if "appendage_displacement" not in ds or "appendage_output_position" not in ds:
        return []
    disp = np.asarray(ds["appendage_displacement"].values, float)[..., :3]
    places = np.asarray(ds["appendage_output_position"].values, float)
    bodies = np.asarray(ds["appendage_output_body"].values)
    names = [str(x) for x in ds["appendage_output"].values]
    return [
        {
            "name": names[p],
            "body": int(bodies[p]),
            "nodes": places[p][None],
            "displacement": scale * disp[:, p][:, None],
        }
        for p in range(len(names))
    ]


def cmd_plot(args) -> int:
    ds = open_result(args.result)
    if not use_matplotlib():
        raise UserError("matplotlib is not installed (pip install 'jaxtree[plot]')")
    res = pathlib.Path(args.result)
    prefix = args.out if args.out else str(res.with_suffix("") if res.suffix == ".nc" else res)
    if ds.attrs.get("kind") == "modes":
        model = model_of(ds, args.result)
        files = [f"{prefix}_shapes.png"]
        existed = existing(files)
        mode_plots.plot_mode_shapes(model, ds, path=files[0])
    else:
        files = [f"{prefix}_histories.png", f"{prefix}_drift.png"]
        existed = existing(files)
        history_plots.plot_histories(ds, files[0])
        history_plots.plot_drift(ds, files[1])
    print(wrote(files, existed))
    return 0
