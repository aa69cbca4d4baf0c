"""3D animation of a tree's motion: one self-contained HTML page that needs no network.

The page shows each body as its *inertia-equivalent box* (the uniform box with the body's
mass and principal moments of inertia), each hinge point with a short line along its axis
(Def. 13: the hinge points ``p^{k N_k}``, the axes ``g^k``), an inertial triad, and plays
either a simulated result (:func:`write_animation`, :func:`animation_html`) or one mode
oscillating (:func:`write_mode_animation`, :func:`mode_html`), with play/pause, speed, a
time slider and a camera under the mouse (drag rotates, shift-drag pans, the wheel zooms).

All geometry is computed here, in Python, with jaxtree's kinematics: the body rotations
``C^{0k}`` (Eqs. 4-5, 21-22) and mass-center positions relative to the system mass center
of :func:`jaxtree.configuration`, vmapped over the frames, turned into inertial components
with the attitude ``C`` of Def. 9 (``{b^0} = C {i}``, so ``v_(i) = C^T v_(0)``). The page
receives per frame and body only a position and a unit quaternion (float32, base64) and
draws: every body-fixed point (box corners, hinge points, axes) is its body's pose applied
to a constant vector.

Why a canvas-2D renderer written here rather than WebGL or plotly's offline bundle: the page
stays small (15 kB of code and style, plus about 37 bytes a body a frame) and fully offline,
needs no new dependency (plotly's offline bundle alone is megabytes), and draws the same
everywhere, including browsers and headless machines without a GPU, where WebGL runs only on
a software fallback (SwiftShader) that depends on the browser's version and flags (headless
Chromium 156 here gives it, with GPU-stall warnings on the console). A few hundred boxes of
flat-shaded faces sorted by depth (painter's algorithm) draw in a few milliseconds (201
bodies: 8 ms a frame in headless Chromium); what it gives up is per-pixel depth, so boxes
that interpenetrate can overlap wrongly at the seam.

For notebooks: ``IPython.display.HTML(jaxtree.viewer.animation_html(...))`` shows the page
inline (everything is scoped to one element with a unique id), or write the file and open
it in ``IPython.display.IFrame``.
"""

from __future__ import annotations

import base64
import hashlib
import html
import importlib.resources
import json
import math
import re

import equinox as eqx
import jax
import numpy as np

from ..atomic import atomic_write
from ..equations.dynamics import configuration
from ..vehicle.model import Model

MAX_FRAMES = 2000  # frames embedded in a page at most (evenly decimated beyond)
MAX_BODY_FRAMES = 250_000  # frames x bodies at most: caps a page near 9 MB for large trees
THIN = 0.02  # a box's smallest half-width at least this share of its largest
MODE_FRAMES = 64  # frames per period of a mode page

_PALETTE = (
    (0.31, 0.47, 0.78),
    (0.90, 0.55, 0.20),
    (0.30, 0.66, 0.42),
    (0.80, 0.33, 0.36),
    (0.55, 0.43, 0.75),
    (0.20, 0.65, 0.72),
    (0.82, 0.70, 0.22),
    (0.60, 0.45, 0.35),
)
_HUB = (0.62, 0.65, 0.70)
_MASSLESS = (0.25, 0.25, 0.25)


# ----------------------------------------------------------------------------- geometry
def inertia_box(mass, inertia):
    """Half-widths and axes of the uniform box with mass `mass` and inertia dyadic `inertia`.

    A uniform box of half-widths ``a1, a2, a3`` along its edges has the principal moments
    ``I1 = m/3 (a2^2 + a3^2)``, ``I2 = m/3 (a1^2 + a3^2)``, ``I3 = m/3 (a1^2 + a2^2)``, so
    ``a1^2 = 3 / (2 m) (I2 + I3 - I1)`` and so on. Negative squares (an inertia that breaks the
    triangle inequality by rounding) are clipped to zero.

    **Arguments:** `mass` (...,), `inertia` (..., 3, 3) about the mass center, body components.

    **Returns:** ``(half, axes)``: half-widths (..., 3) and the principal axes (..., 3, 3), a
    proper rotation whose column i is the box edge of half-width ``half[i]`` in body
    components. Bodies with ``mass <= 0`` get zero half-widths (no box is equivalent).
    """
    mass = np.asarray(mass, dtype=float)
    inertia = np.asarray(inertia, dtype=float)
    inertia = 0.5 * (inertia + np.swapaxes(inertia, -1, -2))
    moments, axes = np.linalg.eigh(inertia)
    flip = np.linalg.det(axes) < 0
    axes[..., :, 2] = np.where(flip[..., None], -axes[..., :, 2], axes[..., :, 2])
    total = moments.sum(-1, keepdims=True)
    safe = np.where(mass > 0, mass, 1.0)[..., None]
    sq = 3.0 / (2.0 * safe) * (total - 2.0 * moments)
    half = np.sqrt(np.clip(sq, 0.0, None))
    half = np.where((mass > 0)[..., None], half, 0.0)
    return half, axes


def poses(model: Model, dcm, gamma):
    """Inertial poses of every body at each frame, from :func:`jaxtree.configuration`.

    **Arguments:** `dcm` (T, 3, 3), C of Def. 9 (``{b^0} = C {i}``); `gamma` (T, n).

    **Returns:** ``(positions, rotations)``: the mass center of each body relative to the
    system mass center (T, n+1, 3) and the rotation taking body-k components to inertial
    components, ``C^T C^{0k}`` (T, n+1, 3, 3), both in inertial components, float64.
    """
    dcm = np.asarray(dcm, dtype=float)
    R, rho = _configs(model, gamma)
    positions = np.einsum("tji,tkj->tki", dcm, rho)
    rotations = np.einsum("tji,tkjl->tkil", dcm, R)
    return positions, rotations


@eqx.filter_jit
def _configurations(model, gamma):
    cfg = jax.vmap(lambda g: configuration(model, g))(gamma)
    return cfg.R, cfg.rho


def _configs(model, gamma):
    """``C^{0k}`` and ``rho_k`` (numpy) of each row of `gamma` (T, n); the rows are padded to a
    power of two so that pages of similar length share one compiled function."""
    gamma = np.asarray(gamma, dtype=float)
    T = gamma.shape[0]
    size = max(8, 1 << (T - 1).bit_length())
    padded = np.concatenate([gamma, np.broadcast_to(gamma[-1:], (size - T, gamma.shape[1]))])
    R, rho = _configurations(model, padded)
    return np.asarray(R, dtype=float)[:T], np.asarray(rho, dtype=float)[:T]


def _quaternions(R):
    """Unit quaternions ``(w, x, y, z)`` of rotation matrices (..., 3, 3) (Shepperd's method:
    of the four rows of ``4 q q^T`` that R gives, take the one with the largest diagonal)."""
    m = R
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    rows = np.stack(
        [
            np.stack(
                [1 + tr, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1
            ),
            np.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 0, 1] + m[..., 1, 0],
                    1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
                    m[..., 1, 2] + m[..., 2, 1],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 1, 0] - m[..., 0, 1],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
                ],
                -1,
            ),
        ],
        -2,
    )
    diag = np.stack([rows[..., i, i] for i in range(4)], -1)
    best = np.argmax(diag, -1)
    q = np.take_along_axis(rows, best[..., None, None], -2)[..., 0, :]
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _decimate(count, bodies, max_frames):
    """Indices of at most `max_frames` (and MAX_BODY_FRAMES / bodies) evenly spread frames,
    the first and the last kept."""
    cap = max(2, min(int(max_frames), MAX_BODY_FRAMES // max(bodies, 1)))
    if count <= cap:
        return np.arange(count)
    return np.unique(np.round(np.linspace(0, count - 1, cap)).astype(int))


def _b64(x):
    return base64.b64encode(np.ascontiguousarray(x, dtype="<f4").tobytes()).decode("ascii")


def _scene_geometry(model, positions, extra=None):
    """Static drawing data: one box per body, one hinge point and axis per hinge (body frames);
    the view's center and radius hold the bodies and the points `extra` (T, p, 3) as well."""
    n = model.n
    mass = np.asarray(model.mass, dtype=float)
    half, axes = inertia_box(mass, np.asarray(model.inertia, dtype=float))
    on_body = np.asarray(model.hinge_on_body, dtype=float).reshape(n, 3)
    on_parent = np.asarray(model.hinge_on_parent, dtype=float).reshape(n, 3)
    g = np.asarray(model.axis, dtype=float).reshape(n, 3)
    # The vehicle's size: mass-center spread over the frames, else hinge offsets, else boxes.
    extent = float(np.max(np.linalg.norm(positions, axis=-1))) if positions.size else 0.0
    if n:
        extent = max(extent, float(np.max(np.linalg.norm(np.concatenate([on_body, on_parent]), axis=-1))))
    extent = extent or float(half.max()) or 1.0
    marker = 0.02 * extent
    bodies = []
    for k in range(n + 1):
        h = half[k]
        point_like = not mass[k] > 0 or h.max() <= 1e-9 * extent
        if point_like:
            h = np.full(3, marker)
        else:
            h = np.maximum(h, max(THIN * h.max(), 0.003 * extent))
        half[k] = h
        color = _MASSLESS if not mass[k] > 0 else (_HUB if k == 0 else _PALETTE[(k - 1) % len(_PALETTE)])
        bodies.append(
            {
                "name": model.names[k],
                "mass": float(mass[k]),
                "half": h.tolist(),
                "axes": axes[k].reshape(-1).tolist(),
                "color": list(color),
                "marker": bool(point_like),
            }
        )
    # A hinge axis relative to body k: C^{0k} g' with g' = C^{k0} C^{0 N_k} g = g (Eq. 4 turns
    # about g), so the axis is the same constant vector in b_k's frame as in its parent's.
    hinges = []
    for k in range(1, n + 1):
        length = float(np.clip(0.6 * half[k].max(), 0.005 * extent, 0.25 * extent))
        hinges.append(
            {
                "body": k,
                "parent": int(model.topology.parents[k - 1]),
                "point": on_body[k - 1].tolist(),
                "axis": g[k - 1].tolist(),
                "half_length": length,
            }
        )
    # The view: the middle of the box that holds every body in every frame, and the radius of
    # the sphere about it that does.
    reach = np.linalg.norm(half, axis=-1)[None, :, None]
    if extra is not None and extra.size:
        positions = np.concatenate([positions, extra], 1)
        reach = np.concatenate([reach, np.zeros((1, extra.shape[1], 1))], 1)
    center = 0.5 * ((positions - reach).min((0, 1)) + (positions + reach).max((0, 1)))
    radius = float(np.max(np.linalg.norm(positions - center, axis=-1) + reach[..., 0]))
    return bodies, hinges, center, radius or 1.0


def _appendage_args(name: str, model, appendages, T: int) -> list[dict]:
    """The drawings of finite-element appendages (:func:`write_animation`), checked: each a dict
    with ``body`` (index), ``nodes`` (n, 3), ``displacement`` (T, n, 3), optional ``edges`` (node
    pairs) and ``name``."""
    out = []
    for i, a in enumerate(appendages or ()):
        if not isinstance(a, dict) or not {"body", "nodes", "displacement"} <= set(a):
            raise ValueError(f"{name}: appendages[{i}] must be a dict with body, nodes and displacement")
        body = int(a["body"])
        if not 0 <= body <= model.n:
            raise ValueError(f"{name}: appendages[{i}] is fixed to body {body}, not in 0..{model.n}")
        nodes = np.asarray(a["nodes"], float)
        disp = np.asarray(a["displacement"], float)
        if nodes.ndim != 2 or nodes.shape[1] != 3 or disp.shape != (T, nodes.shape[0], 3):
            raise ValueError(
                f"{name}: appendages[{i}]: nodes must be (n, 3) and displacement (T, n, 3) = ({T}, n, 3), "
                f"got {nodes.shape} and {disp.shape}"
            )
        if not (np.isfinite(nodes).all() and np.isfinite(disp).all()):
            raise ValueError(f"{name}: appendages[{i}] has non-finite nodes or displacements")
        edges = np.asarray(a.get("edges", ()), np.int64).reshape(-1, 2)
        if edges.size and (edges.min() < 0 or edges.max() >= nodes.shape[0]):
            raise ValueError(f"{name}: appendages[{i}] has an edge outside its {nodes.shape[0]} nodes")
        out.append(
            {"name": str(a.get("name", f"appendage{i}")), "body": body, "points": nodes[None] + disp, "edges": edges}
        )
    return out


def _page(model, times, dcm, gamma, *, title, subtitle, speed, period, kind, appendages=()):
    positions, rotations = poses(model, dcm, gamma)
    # the appendages' points in every frame, in the view's bounds
    world = [
        positions[:, a["body"], None, :] + np.einsum("tij,tnj->tni", rotations[:, a["body"]], a["points"])
        for a in appendages
    ]
    bodies, hinges, center, radius = _scene_geometry(model, positions, np.concatenate(world, 1) if world else None)
    data = {
        "format": "jaxtree-animation/1",
        "kind": kind,
        "title": title,
        "subtitle": subtitle,
        "bodies": bodies,
        "hinges": hinges,
        "times": [float(t) for t in times],
        "positions": _b64(positions),
        "quaternions": _b64(_quaternions(rotations)),
        "center": center.tolist(),
        "radius": radius,
        "speed": float(speed),
        "period": None if period is None else float(period),
        "appendages": [
            {
                "name": a["name"],
                "body": a["body"],
                "n": int(a["points"].shape[1]),
                "edges": a["edges"].tolist(),
                "points": _b64(a["points"]),
            }
            for a in appendages
        ],
    }
    text = json.dumps(data, separators=(",", ":"), allow_nan=False)
    root = "jaxtree-" + hashlib.sha1(text.encode()).hexdigest()[:12]
    # Inside <script> only "</script" and "<!--" matter; escaping every "<", ">" and "&" as
    # JSON's \\u escapes keeps the block inert whatever the names and the title contain.
    text = text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")
    template = importlib.resources.files("jaxtree").joinpath("viewer.html").read_text(encoding="utf-8")
    values = {"ROOT": root, "TITLE": html.escape(title), "SUBTITLE": html.escape(subtitle), "DATA": text}
    return re.sub(r"__(ROOT|TITLE|SUBTITLE|DATA)__", lambda m: values[m.group(1)], template)


def _finite_rows(name, ts, dcm, gamma, n):
    ts = np.asarray(ts, dtype=float)
    dcm = np.asarray(dcm, dtype=float)
    gamma = np.asarray(gamma, dtype=float)
    if ts.ndim != 1:
        raise ValueError(f"{name}: ts must have shape (T,), got {ts.shape}")
    T = ts.shape[0]
    if dcm.shape != (T, 3, 3):
        raise ValueError(
            f"{name}: dcm has shape {dcm.shape}; expected (T, 3, 3) = {(T, 3, 3)} (one C of Def. 9 per time)"
        )
    if gamma.shape != (T, n):
        raise ValueError(f"{name}: gamma has shape {gamma.shape}; the model with {n} hinges needs (T, n) = {(T, n)}")
    keep = np.isfinite(ts)  # a run that stopped early pads its save times with inf
    ts, dcm, gamma = ts[keep], dcm[keep], gamma[keep]
    if not ts.size:
        raise ValueError(f"{name}: no finite time in ts")
    if np.any(np.diff(ts) < 0):
        raise ValueError(f"{name}: ts must be nondecreasing")
    for field, x in (("dcm", dcm), ("gamma", gamma)):
        bad = ~np.isfinite(x.reshape(x.shape[0], -1)).all(-1)
        if bad.any():
            raise ValueError(f"{name}: {field} is not finite at t = {ts[np.argmax(bad)]:.6g}")
    return ts, dcm, gamma


def _default_speed(duration):
    """Real time for runs of 1 s to 1 min; otherwise a speed that plays the run in 10 s."""
    if duration <= 0 or 1.0 <= duration <= 60.0:
        return 1.0
    return duration / 10.0


# ----------------------------------------------------------------------------- results
def animation_html(model: Model, ts, dcm, gamma, *, title=None, max_frames: int = MAX_FRAMES, appendages=None) -> str:
    """The HTML page of :func:`write_animation` as a string (e.g. for ``IPython.display.HTML``)."""
    every = np.asarray(ts, dtype=float)
    ts, dcm, gamma = _finite_rows("animation_html", ts, dcm, gamma, model.n)
    apps = _appendage_args("animation_html", model, appendages, every.shape[0])
    keep = np.isfinite(every)
    saved = ts.shape[0]
    idx = _decimate(saved, model.n + 1 + sum(a["points"].shape[1] for a in apps) // 4, max_frames)
    ts, dcm, gamma = ts[idx], dcm[idx], gamma[idx]
    for a in apps:
        a["points"] = a["points"][keep][idx]
    title = (model.name or "jaxtree") if title is None else str(title)
    duration = float(ts[-1] - ts[0])
    subtitle = f"{model.n + 1} bodies, t = {ts[0]:.6g} .. {ts[-1]:.6g} s, {ts.size} frames" + (
        f" (of {saved} saved)" if ts.size < saved else ""
    )
    return _page(
        model,
        ts,
        dcm,
        gamma,
        title=title,
        subtitle=subtitle,
        speed=_default_speed(duration),
        period=None,
        kind="result",
        appendages=apps,
    )


def write_animation(
    path, model: Model, ts, dcm, gamma, *, title=None, max_frames: int = MAX_FRAMES, appendages=None
) -> None:
    """Write an HTML page (atomically) animating a trajectory of `model`.

    **Arguments:**

    - `ts` (T,) times; rows with a non-finite time (a run that stopped early) are dropped;
    - `dcm` (T, 3, 3): the attitude of b_0, C of Def. 9 (``{b^0} = C {i}``), e.g. ``sol.dcm``;
    - `gamma` (T, n): all hinge angles, e.g. ``sol.gamma``;
    - `title`: shown on the page (default: the model's name);
    - `max_frames`: at most this many evenly spread frames are embedded (and at most
      ``MAX_BODY_FRAMES / (n + 1)``), the first and last included;
    - `appendages`: finite-element appendages drawn on their bodies, each a dict with ``body``
      (index), ``nodes`` (n, 3: undeformed, from the body's mass center, its frame),
      ``displacement`` (T, n, 3: the nodes' translations at each time, body's frame, scaled as
      they are to be drawn), optional ``edges`` (node pairs joined by lines; points otherwise)
      and ``name``: :meth:`jaxtree.HybridSolution.appendage_motion` gives them.

    The page plays in real time for runs of 1 s to a minute, else at a speed that plays the run
    in about 10 s; its speed control spans a factor of 1000 either way.
    """
    text = animation_html(model, ts, dcm, gamma, title=title, max_frames=max_frames, appendages=appendages)
    with atomic_write(path, "w") as fh:
        fh.write(text)


# ----------------------------------------------------------------------------- modes
def expand_shape(model: Model, hinges, vector):
    """A mode's vector over the small coordinates of a linearization, spread over the model.

    **Arguments:** `hinges`: a :class:`~jaxtree.LinearSystem` (its ``hinges``) or the hinge
    index 1..n of each coordinate, 0 for an attitude angle of b_0 (:func:`jaxtree.linearize_vehicle`);
    `vector` (nu,), e.g. ``modes.shapes[:, j]``.

    **Returns:** ``(shape, rotation)``: the hinge angles (n,) (zero on hinges not in the set),
    and the three small attitude angles of b_0 (3,), or None when the linearization has none.
    Both are complex if `vector` is.
    """
    idx = tuple(getattr(hinges, "hinges", hinges))
    vector = np.asarray(vector)
    if vector.shape != (len(idx),):
        raise ValueError(f"expand_shape: vector has shape {vector.shape}; the linearization has {len(idx)} coordinates")
    dtype = np.result_type(vector, float)
    shape = np.zeros(model.n, dtype)
    rotation = np.zeros(3, dtype)
    attitude = [i for i, k in enumerate(idx) if k == 0]
    if attitude and len(attitude) != 3:
        raise ValueError(f"expand_shape: {len(attitude)} attitude coordinates (hinge index 0); expected 0 or 3")
    for i, k in enumerate(idx):
        if k:
            if not 1 <= k <= model.n:
                raise ValueError(f"expand_shape: hinge index {k} outside 1..{model.n}")
            shape[k - 1] = vector[i]
    rotation[:] = vector[attitude] if attitude else 0
    return shape, (rotation if attitude else None)


def _rotation_matrices(theta):
    """exp(tilde(theta)) for (T, 3) rotation vectors (Rodrigues)."""
    angle = np.linalg.norm(theta, axis=-1)[:, None, None]
    safe = np.where(angle > 0, angle, 1.0)
    k = theta / safe[:, :, 0]
    K = np.zeros(theta.shape[:-1] + (3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K = K - np.swapaxes(K, -1, -2)
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)


def _default_amplitude(model, gamma0, shape, rotation):
    """The amplitude that moves some mass center by 15 % of the vehicle's radius, or turns the
    largest angle by 0.35 rad (20 deg), whichever is smaller."""
    parts = [np.abs(shape)] + ([] if rotation is None else [np.abs(rotation)])
    peak = float(max(p.max(initial=0.0) for p in parts))
    if peak == 0:
        raise ValueError("write_mode_animation: the mode shape is zero")
    h = 1e-4 / peak
    rows = []
    for part in (shape.real, shape.imag):
        rows += [gamma0 + h * part, gamma0 - h * part]
    _, rho = _configs(model, np.stack(rows))
    disp = np.linalg.norm(rho[0::2] - rho[1::2], axis=-1).max() / (2 * h)
    size = float(np.linalg.norm(rho[0], axis=-1).max())
    if rotation is not None:
        disp += float(np.abs(rotation).max()) * size
    amp = 0.35 / peak
    if disp > 0 and size > 0:
        amp = min(amp, 0.15 * size / disp)
    return amp


def mode_html(model: Model, shape, frequency, *, gamma=None, amplitude=None, title=None, rotation=None) -> str:
    """The HTML page of :func:`write_mode_animation` as a string."""
    n = model.n
    shape = np.asarray(shape)
    if shape.shape != (n,):
        raise ValueError(
            f"write_mode_animation: shape has shape {shape.shape}; the model with {n} hinges needs "
            f"({n},) (use jaxtree.viewer.expand_shape for a linearization's coordinates)"
        )
    shape = shape.astype(np.result_type(shape, float))
    if rotation is not None:
        rotation = np.asarray(rotation).astype(np.result_type(np.asarray(rotation), float))
        if rotation.shape != (3,):
            raise ValueError(f"write_mode_animation: rotation has shape {rotation.shape}; expected (3,)")
    if not np.all(np.isfinite(shape)) or (rotation is not None and not np.all(np.isfinite(rotation))):
        raise ValueError("write_mode_animation: the mode shape is not finite")
    gamma0 = np.asarray(model.initial.gamma if gamma is None else gamma, dtype=float)
    if gamma0.shape != (n,):
        raise ValueError(f"write_mode_animation: gamma has shape {gamma0.shape}; expected ({n},)")
    frequency = float(frequency)
    if not math.isfinite(frequency) or frequency < 0:
        raise ValueError(f"write_mode_animation: frequency must be finite and >= 0 (rad/s), got {frequency}")
    amplitude = _default_amplitude(model, gamma0, shape, rotation) if amplitude is None else float(amplitude)
    rigid = frequency <= 0
    period = 2.0 if rigid else 2 * math.pi / frequency
    ts = np.arange(MODE_FRAMES) * (period / MODE_FRAMES)
    phase = np.exp(2j * np.pi * ts / period)
    # Im(shape e^{i w t}) = shape sin(w t) for a real shape; a complex (gyroscopic) shape turns.
    gamma = gamma0[None, :] + amplitude * np.imag(shape[None, :] * phase[:, None])
    if rotation is None:
        dcm = np.broadcast_to(np.eye(3), (MODE_FRAMES, 3, 3))
    else:  # b_0 = (U - tilde(theta)) {f} (linearize_vehicle), i.e. C = exp(-tilde(theta)) to first order
        theta = amplitude * np.imag(rotation[None, :] * phase[:, None])
        dcm = _rotation_matrices(-theta)
    peak = amplitude * float(max(np.abs(shape).max(initial=0.0), 0.0 if rotation is None else np.abs(rotation).max()))
    if rigid:
        what = "zero-frequency (rigid) mode, shown with a 2 s period"
    else:
        what = f"mode at {frequency:.6g} rad/s ({frequency / (2 * math.pi):.4g} Hz, period {period:.4g} s)"
    subtitle = f"{what}; largest angle {peak:.3g} rad"
    title = (model.name or "jaxtree") + " mode" if title is None else str(title)
    return _page(model, ts, dcm, gamma, title=title, subtitle=subtitle, speed=period / 2.0, period=period, kind="mode")


def write_mode_animation(
    path, model: Model, shape, frequency, *, gamma=None, amplitude=None, title=None, rotation=None
) -> None:
    """Write an HTML page (atomically) oscillating one mode: the hinge angles
    ``gamma + amplitude * shape * sin(2 pi t / period)``, ``period = 2 pi / frequency``.

    **Arguments:**

    - `shape` (n,): the mode over all hinges (:func:`expand_shape` spreads a linearization's
      ``modes.shapes[:, j]``); a complex shape (gyroscopic modes) plays
      ``Im(shape e^{i 2 pi t / period})``, its real part a quarter period behind;
    - `frequency`: the mode's frequency in rad/s (``modes.frequencies[j]``); zero shows a
      rigid-body mode with a 2 s display period;
    - `gamma` (n,): the nominal angles (default the model's initial angles);
    - `amplitude`: the factor on `shape` (default: a mass center moves by 15 % of the vehicle's
      radius, or the largest angle is 0.35 rad, whichever is smaller);
    - `rotation` (3,): the mode's small attitude angles of b_0 (:func:`jaxtree.linearize_vehicle`),
      applied as ``C = exp(-tilde(amplitude theta(t)))``; default none (b_0's axes stay on {i}).

    The page loops over one period, by default in 2 s.
    """
    text = mode_html(model, shape, frequency, gamma=gamma, amplitude=amplitude, title=title, rotation=rotation)
    with atomic_write(path, "w") as fh:
        fh.write(text)
