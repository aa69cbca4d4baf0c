"""The keys of the scene format's objects: an unknown key is an error that names the nearest known
one, a key of the user's own begins with :data:`EXTENSION_PREFIX`."""

from __future__ import annotations

import difflib

from ..errors import SceneError

# A key that begins with this is an extension of the user's (a note, a tool's own data): read past
# silently and not written back. Any other unknown key is an error: a misspelt "initial" would
# otherwise simulate the vehicle at rest.
EXTENSION_PREFIX = "x-"


def unknown_keys(given, known, where: str) -> None:
    """Refuse (:class:`SceneError`) the first key of `given` that is neither in `known` nor an
    extension key (:data:`EXTENSION_PREFIX`), naming it, its place and the nearest known key."""
    for key in given:
        if key in known or str(key).startswith(EXTENSION_PREFIX):
            continue
        close = difflib.get_close_matches(str(key), [str(k) for k in known], n=1)
        hint = f"did you mean {close[0]!r}?" if close else f"known: {sorted(map(str, known))}"
        raise SceneError(f"{where}: unknown key {key!r} ({hint}; a key of your own begins with {EXTENSION_PREFIX!r})")
