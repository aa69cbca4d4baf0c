"""``jaxtree check``: validate a scene and describe it; and ``jaxtree identify``, whose work is
in :mod:`jaxtree._src.identify.command`, given its scene here."""

from __future__ import annotations

import dataclasses
import pathlib

from ..identify import command as identify_command
from ..scene.check import check_scene
from ..scene.scene import SceneError
from .common import UserError, open_scene, use_matplotlib


def cmd_identify(args) -> int:
    model = open_scene(args.scene)
    try:
        return identify_command.run(args, model, matplotlib_ok=not args.no_plot and use_matplotlib())
    except SceneError as e:
        raise UserError(str(e).removeprefix("identify: ")) from None


def cmd_check(args) -> int:
    model = open_scene(args.scene)
    src = pathlib.Path(args.scene)
    report = dataclasses.replace(
        check_scene(model), source=str(src) if src.exists() else f"bundled scene {args.scene!r}"
    )
    print(report.format(tables=True if args.tables else None))
    return 0
