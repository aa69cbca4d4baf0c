"""The notebooks of notebooks/ (quickstart, modes and hybrid coordinates, identification, Monte
Carlo, finite-element appendages) are stored executed top to bottom with their outputs, and run again here, top to bottom, in
a fresh Jupyter kernel of this Python (nbclient, as nbmake does).

The checks are the notebooks' own cells: each asserts what it shows against an independent source
(conservation of angular momentum, the motor's work against the energy change, dense against
articulated Eq. (1), Appendix C's closed forms for the modes, their shapes and the frequencies'
stiffness derivative, the hybrid equations against the full Eq. (1) to second order in the
amplitude, C-74's decoupling, six alike wings against one wing on an immovable bus, a fit within
its standard errors with white residuals). A failing cell fails its notebook's test with the cell
and the traceback. identify_wings.ipynb runs examples/identify_wings.py's fit: it is that
example's test.

To refresh a notebook's stored outputs after editing it (``pip install -e ".[notebooks]"``), from
the repository root:
``jupyter nbconvert --execute --to notebook --inplace notebooks/NAME.ipynb``.
"""

import pathlib
import shutil
import sys

import nbformat
import pytest
from jupyter_client.kernelspec import KernelSpecManager
from jupyter_client.manager import KernelManager
from nbclient import NotebookClient

NOTEBOOKS = sorted((pathlib.Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
MAX_BYTES = 300_000  # outputs stay small: figures at 120 dpi of a few panels, 3D pages of a few dozen frames


def test_the_guide_lists_every_notebook_and_every_listed_one_is_there():
    """docs/guide.md's list of notebooks and the notebooks/ folder name the same five files, and
    each link of the guide leads to one (a notebook removed, renamed or added without the guide
    fails here; the test below runs every notebook found)."""
    import re

    guide = (pathlib.Path(__file__).resolve().parents[1] / "docs" / "guide.md").read_text()
    linked = set(re.findall(r"\]\(\.\./notebooks/([A-Za-z0-9_]+\.ipynb)\)", guide))
    assert linked == {p.name for p in NOTEBOOKS}, (sorted(linked), [p.name for p in NOTEBOOKS])
    assert len(linked) == 5


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_is_stored_executed_and_runs(path, tmp_path):
    """The stored file: every code cell was run once, in order, in one kernel (execution counts
    1, 2, ...), none raised, each shows an output, and the file stays small. Then the code cells
    run again in a fresh kernel (working directory a copy of notebooks/); the stored files are left as they are."""
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert [c.execution_count for c in code] == list(range(1, len(code) + 1)), (
        f"{path.name}: not stored executed top to bottom; refresh it (see this module's docstring)"
    )
    assert not [o for c in code for o in c.outputs if o.output_type == "error"]
    assert all(c.outputs for c in code), f"{path.name}: a code cell shows nothing"
    assert path.stat().st_size < MAX_BYTES, f"{path.name}: {path.stat().st_size} bytes"

    # "python3" is this interpreter: only the native kernel spec is looked up (no user-level
    # kernel of another Python can stand in for it)
    km = KernelManager(kernel_name="python3", kernel_spec_manager=KernelSpecManager(kernel_dirs=[]))
    assert km.kernel_spec.argv[0] == sys.executable
    # run in a copy of notebooks/ beside the repository's examples/ (a notebook imports from
    # ../examples): the figures its cells save land there, not over the stored ones
    work = tmp_path / "notebooks"
    shutil.copytree(path.parent, work, ignore=shutil.ignore_patterns(".ipynb_checkpoints"))
    (tmp_path / "examples").symlink_to(path.parents[1] / "examples", target_is_directory=True)
    # a kernel that starts importing JAX on a loaded 2-core machine can take over the default 60 s
    try:
        NotebookClient(
            nb, km=km, timeout=600, startup_timeout=300, resources={"metadata": {"path": str(work)}}
        ).execute()
    finally:  # the client does not stop a kernel manager it was given
        if km.has_kernel:
            km.shutdown_kernel(now=True)
    assert [c.execution_count for c in nb.cells if c.cell_type == "code"] == list(range(1, len(code) + 1))
