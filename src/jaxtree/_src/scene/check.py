"""What ``jaxtree check SCENE`` prints: :func:`check_scene`.

The scene validated, its tree drawn with each body's hinge and law, the seed's Tables 1-2 for it
(network elements N_kr of Def. 26, path elements epsilon_sk of Def. 27), the masses, the loads and
laws it carries, and the condition number of Eq. (1) at the initial state
(:func:`jaxtree.condition`) with a warning where digits are lost.
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np

from ..equations.diagnostics import POOR_CONDITION, Condition, condition
from ..equations.dynamics import SINGULAR_CONDITION
from ..errors import SceneError
from ..vehicle.model import Model, SinePrescription
from .files import load_scene, scene_from_dict
from .laws import describe_laws


def _joint_text(model: Model, k: int) -> str:
    kind = model.joints[k - 1]
    if k in model.prescribed:
        pres = model.prescription
        if isinstance(pres, SinePrescription):
            i = list(pres.hinges).index(k)
            return (
                f"prescribed gamma = {float(pres.amplitude[i]):g} sin({float(pres.frequency[i]):g} t "
                f"+ {float(pres.phase[i]):g})"
            )
        return "prescribed"
    if k in model.sprung:
        stiffness, damping = float(np.asarray(model.stiffness)[k - 1]), float(np.asarray(model.damping)[k - 1])
        return f"spring {stiffness:g} N m/rad, damper {damping:g} N m s/rad"
    return "free" if kind in ("free", "") else kind


def _tree_lines(model: Model) -> list[str]:
    """An indented drawing of the tree: each body under its parent with its hinge."""
    topo = model.topology
    masses, axes = np.asarray(model.mass, float), np.asarray(model.axis, float)  # on the host: no program per index
    lines = [f"0 {model.names[0]}  (reference body b0, {masses[0]:g} kg)"]

    def walk(k, prefix):
        kids = topo.children[k]
        for i, c in enumerate(kids):
            last = i == len(kids) - 1
            g = axes[c - 1]
            mass = float(masses[c])
            tags = []
            if c in model.inert:
                tags.append("inert: only massless bodies outboard")
            text = (
                f"{prefix}{'`-- ' if last else '|-- '}{c} {model.names[c]}  ({mass:g} kg"
                f"{', massless' if mass == 0 else ''}); hinge {c} about "
                f"[{g[0]:.3g}, {g[1]:.3g}, {g[2]:.3g}]: {_joint_text(model, c)}"
            )
            if tags:
                text += f" [{'; '.join(tags)}]"
            lines.append(text)
            walk(c, prefix + ("    " if last else "|   "))

    walk(0, "")
    return lines


def _table(title, rows, row_labels, col_labels, corner):
    width = max(2, max(len(str(c)) for c in col_labels), max((len(str(x)) for r in rows for x in r), default=1))
    lw = max(len(corner), max(len(str(r)) for r in row_labels))
    head = f"{corner:>{lw}} | " + " ".join(f"{c:>{width}}" for c in col_labels)
    out = [title, head, "-" * len(head)]
    for label, row in zip(row_labels, rows):
        out.append(f"{label:>{lw}} | " + " ".join(f"{int(x):>{width}}" for x in row))
    return out


@dataclasses.dataclass(frozen=True)
class SceneReport:
    """What :func:`check_scene` found (its ``str`` is the text of ``jaxtree check``).

    `model`; `source` (where the scene came from); `tree` (lines of the indented tree);
    `network_elements` ((n+1, n+1), N_kr of Def. 26, the seed's Table 1); `path_elements`
    ((n, n+1), epsilon_sk of Def. 27, the seed's Table 2); `masses` (n+1,), `total_mass`;
    `condition` (:class:`Condition` of Eq. 1 at the initial state); `warnings` (lines).
    """

    model: Model
    source: str
    tree: tuple[str, ...]
    network_elements: np.ndarray
    path_elements: np.ndarray
    masses: np.ndarray
    total_mass: float
    condition: Condition
    warnings: tuple[str, ...]

    def format(self, tables: bool | None = None) -> str:
        """The report as text; `tables` prints Tables 1-2 (default: for up to 20 hinges)."""
        m = self.model
        n = m.n
        if tables is None:
            tables = n <= 20
        lines = [f"scene {m.name!r} ({self.source}): valid; {n + 1} bodies, {n} hinges"]
        lines.append(
            f"  prescribed hinges: {list(m.prescribed) or 'none'}; sprung: {list(m.sprung) or 'none'}; "
            f"inert: {list(m.inert) or 'none'}; unknowns of Eq. (1): 3 + {len(m.unknown_hinges)}"
        )
        laws = describe_laws(m)
        if laws:
            lines += ["", "loads and laws (applied by jaxtree simulate):", *laws]
        lines += ["", "tree (body index, name, mass; hinge k joins body k to its parent):"]
        lines += ["  " + s for s in self.tree]
        if m.appendages:
            lines += ["", "finite-element appendages (in hybrid coordinates only; jaxtree.scene_appendages):"]
            for a in m.appendages:
                source = "beam" if a.beam is not None else "plate" if a.plate is not None else f"file {a.file}"
                lines.append(f"  {a.name}: on {a.body!r} at {list(a.point)}, {source}, modes {a.modes}")
        if tables and n == 0:
            lines += ["", "Tables 1-2: none (the tree has no hinges)"]
        elif tables:
            idx = list(range(n + 1))
            lines.append("")
            lines += _table(
                "Table 1: network elements N_kr (Def. 26; column 0 is the input N_k)",
                self.network_elements,
                idx,
                idx,
                "k\\r",
            )
            lines.append("")
            lines += _table(
                "Table 2: path elements epsilon_sk (Def. 27: 1 iff hinge s lies between b0 and b_k)",
                self.path_elements,
                list(range(1, n + 1)),
                idx,
                "s\\k",
            )
        else:
            lines += [
                "",
                f"Tables 1-2 ({n + 1} x {n + 1} and {n} x {n + 1}) not shown for {n} hinges "
                "(jaxtree check --tables prints them)",
            ]
        lines += ["", "masses (kg):"]
        for k in range(n + 1):
            lines.append(f"  {k:3d} {m.names[k]:<20s} {self.masses[k]:12.6g}")
        lines.append(f"  total {self.total_mass:.6g} kg")
        s = m.initial
        lines += [
            "",
            f"at the initial state (omega0 = {np.asarray(s.omega0).tolist()} rad/s, "
            f"max |gamma| = {float(np.max(np.abs(np.asarray(s.gamma)), initial=0.0)):.3g} rad):",
        ]
        lines.append("  " + self.condition.describe())
        if self.warnings:
            lines += [""] + [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.format()


def check_scene(scene) -> SceneReport:
    """Validate a scene and describe it (the ``jaxtree check`` command).

    `scene`: a path to a ``jaxtree-scene/1`` JSON file, a bundled scene name (``"fig4"``), a
    parsed scene dict, or a :class:`~jaxtree.Model`. Raises :class:`~jaxtree.SceneError` naming
    the body and the field of an invalid scene (``FileNotFoundError`` for a missing file).
    Returns a :class:`SceneReport` (``print(report)`` shows the text).
    """
    if isinstance(scene, Model):
        model, source = scene, "model"
    elif isinstance(scene, dict):
        model, source = scene_from_dict(scene), "dict"
    elif isinstance(scene, (str, pathlib.Path)):
        p = pathlib.Path(scene)
        try:
            model = load_scene(scene)
        except UnicodeDecodeError:
            raise SceneError(f"{p}: not a text (JSON) file") from None
        except IsADirectoryError:
            raise SceneError(f"{p}: is a folder, not a scene file") from None
        source = str(p) if p.exists() else f"bundled scene {str(scene)!r}"
    else:
        raise TypeError(f"check_scene: expected a path, a scene name, a dict or a Model, got {type(scene).__name__}")
    topo = model.topology
    masses = np.asarray(model.mass, dtype=float)
    cond = condition(model)
    warnings = []
    c = float(cond.number)
    if not np.isfinite(c) or c > SINGULAR_CONDITION:
        warnings.append(
            f"Eq. (1) is singular at the initial state (condition number {c:.3g}): a simulation "
            "will stop at once; see the near-null direction above"
        )
    elif c > POOR_CONDITION:
        warnings.append(
            f"Eq. (1) is poorly conditioned at the initial state ({c:.3g}): accelerations lose "
            f"about {np.log10(c):.0f} digits (float32 keeps none)"
        )
    if model.inert:
        warnings.append(
            f"hinges {list(model.inert)} have nothing but massless bodies outboard: they are not "
            "unknowns of Eq. (1) and stay at their initial rates"
        )
    return SceneReport(
        model=model,
        source=source,
        tree=tuple(_tree_lines(model)),
        network_elements=np.asarray(topo.network_elements),
        path_elements=np.asarray(topo.path_elements),
        masses=masses,
        total_mass=float(masses.sum()),
        condition=cond,
        warnings=tuple(warnings),
    )
