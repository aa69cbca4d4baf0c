"""Finite-element appendages in files: a structure's matrices and nodes, or an appendage's
precomputed modal invariants, as ``.npz`` (numpy's zip of arrays), and the matrices that
finite-element tools export in MatrixMarket form (Abaqus, ANSYS; read by scipy).

**Schema** ``jaxtree-fe/1`` (:func:`save_fe`, :func:`load_fe`), keys:

- ``format``: the string ``"jaxtree-fe/1"``;
- ``mass``, ``stiffness``: (N, N) dense, or sparse as ``mass_rows``, ``mass_cols``,
  ``mass_values`` (and ``stiffness_...``) plus ``size`` = N: coordinate entries, duplicates summed
  (the form of an element-by-element assembly); a file may give only the upper or lower triangle
  with ``triangle`` = ``"upper"`` / ``"lower"``, mirrored on reading;
- ``nodes``: (n_nodes, 3) positions in the structure's frame; ``dofs``: 6 (translations, then
  small rotations, node by node) or 3;
- optional, for the geometric stiffness of two-node beam elements: ``element_nodes`` (ne, 2),
  ``element_frame`` (ne, 3, 3; rows the local x, y, z axes), ``element_length`` (ne,),
  ``element_axial`` (ne,: EA / L), with ``element_line_mass`` (ne,: rho A) and
  ``element_polar_mass`` (ne,: rho (Iy + Iz)) for the exact inertia of the beam's interpolated
  fields in the rotating frame (:class:`~jaxtree._src.appendage.fe.Samples`; without them the
  nodes are weighted by the mass matrix); or of a flat plate's four-node elements (:func:`jaxtree.plate`):
  ``plate_nodes`` (ne, 4), ``plate_normal`` (3,), ``plate_axes`` (2, 3), ``plate_dN`` (ng, 2, 4),
  ``plate_weights`` (ng,), ``plate_membrane`` (3, 3) (:class:`~jaxtree._src.appendage.fe.PlateElements`).

**Schema** ``jaxtree-appendage/1`` (:func:`save_appendage`, :func:`load_appendage`): the arrays of an
:class:`~jaxtree._src.appendage.model.Appendage` (its modes, rigid invariants, participations
and the Taylor terms ``A0, A1, G0, G1, G2`` of its share of Eq. 30) under their own names, with
``interface``, ``outputs``, ``dofs``, ``geometric`` and ``body`` (a string, or an integer index).
A file written from one build and read back gives the same appendage to the last bit.
"""

from __future__ import annotations

import pathlib

import jax.numpy as jnp
import numpy as np

from ..atomic import atomic_write
from ..errors import SceneError
from ..hybrid.substructure import Terms
from .fe import Elements, FEModel, PlateElements
from .model import Appendage

FE_FORMAT = "jaxtree-fe/1"
APPENDAGE_FORMAT = "jaxtree-appendage/1"
_TERMS = ("A0", "A1", "G0", "G1", "G2")
_ARRAYS = (
    "point",
    "frame",
    "frequencies",
    "damping",
    "shapes",
    "nodes",
    "mass",
    "first_moment",
    "inertia",
    "participation",
    "all_frequencies",
)


def _write(path, arrays: dict) -> None:
    with atomic_write(path) as fh:
        np.savez_compressed(fh, **arrays)


def _open(path, fmt: str) -> dict:
    path = pathlib.Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: no such file")
    try:
        with np.load(path, allow_pickle=False) as data:
            out = {k: data[k] for k in data.files}
    except (OSError, ValueError) as exc:
        raise SceneError(f"{path}: not a readable .npz file ({exc})") from None
    got = str(out.get("format", ""))
    if got != fmt:
        raise SceneError(f"{path}: format {got!r}, expected {fmt!r}")
    return out


def save_fe(path, fe: FEModel) -> None:
    """Write `fe` to `path` (``jaxtree-fe/1``, dense matrices), atomically."""
    arrays = {
        "format": np.asarray(FE_FORMAT),
        "mass": np.asarray(fe.mass),
        "stiffness": np.asarray(fe.stiffness),
        "nodes": np.asarray(fe.nodes),
        "dofs": np.asarray(fe.dofs),
    }
    if isinstance(fe.elements, PlateElements):
        el = fe.elements
        arrays.update(
            plate_nodes=np.asarray(el.nodes, np.int64),
            plate_normal=np.asarray(el.normal),
            plate_axes=np.asarray(el.axes),
            plate_dN=np.asarray(el.dN),
            plate_weights=np.asarray(el.weights),
            plate_membrane=np.asarray(el.membrane),
        )
    elif fe.elements is not None:
        el = fe.elements
        arrays.update(
            element_nodes=np.asarray(el.nodes, np.int64),
            element_frame=np.asarray(el.frame),
            element_length=np.asarray(el.length),
            element_axial=np.asarray(el.axial),
        )
        if el.line_mass is not None and el.polar_mass is not None:
            arrays.update(element_line_mass=np.asarray(el.line_mass), element_polar_mass=np.asarray(el.polar_mass))
    _write(path, arrays)


def _matrix(data: dict, name: str, N: int, path) -> np.ndarray:
    if name in data:
        A = np.asarray(data[name], float)
        if A.shape != (N, N):
            raise SceneError(f"{path}: {name} has shape {A.shape}, expected ({N}, {N})")
    else:
        keys = [f"{name}_{k}" for k in ("rows", "cols", "values")]
        if not all(k in data for k in keys):
            raise SceneError(f"{path}: no {name} (dense) nor {', '.join(keys)} (coordinate entries)")
        r, c, v = (np.asarray(data[k]) for k in keys)
        if not (r.shape == c.shape == v.shape) or r.ndim != 1:
            raise SceneError(f"{path}: {', '.join(keys)} must be equal-length vectors")
        if r.size and (min(r.min(), c.min()) < 0 or max(r.max(), c.max()) >= N):
            raise SceneError(f"{path}: {name} has an entry outside 0..{N - 1}")
        A = np.zeros((N, N))
        np.add.at(A, (r.astype(np.int64), c.astype(np.int64)), v.astype(float))
    tri = str(data.get("triangle", ""))
    if tri in ("upper", "lower"):
        A = A + A.T - np.diag(np.diag(A))
    elif tri:
        raise SceneError(f"{path}: triangle must be 'upper' or 'lower', got {tri!r}")
    if not np.all(np.isfinite(A)):
        raise SceneError(f"{path}: {name} has non-finite entries")
    asym = np.max(np.abs(A - A.T)) if A.size else 0.0
    if asym > 1e-9 * max(np.max(np.abs(A)), 1e-300):
        raise SceneError(f"{path}: {name} is not symmetric (largest difference {asym:.3g})")
    return A


def load_fe(path) -> FEModel:
    """Read a ``jaxtree-fe/1`` file (module docstring) into an :class:`FEModel`."""
    data = _open(path, FE_FORMAT)
    if "nodes" not in data:
        raise SceneError(f"{path}: no nodes")
    nodes = np.asarray(data["nodes"], float)
    if nodes.ndim != 2 or nodes.shape[1] != 3:
        raise SceneError(f"{path}: nodes must be (n_nodes, 3), got {nodes.shape}")
    dofs = int(data.get("dofs", 6))
    if dofs not in (3, 6):
        raise SceneError(f"{path}: dofs must be 3 or 6, got {dofs}")
    N = dofs * nodes.shape[0]
    M = _matrix(data, "mass", N, path)
    K = _matrix(data, "stiffness", N, path)
    elements = None
    if "element_nodes" in data:
        en = np.asarray(data["element_nodes"], np.int64)
        ne = en.shape[0]
        if en.shape != (ne, 2) or en.min(initial=0) < 0 or en.max(initial=0) >= nodes.shape[0]:
            raise SceneError(f"{path}: element_nodes must be (ne, 2) node indices")
        parts = {k: np.asarray(data[f"element_{k}"], float) for k in ("frame", "length", "axial")}
        if parts["frame"].shape != (ne, 3, 3) or parts["length"].shape != (ne,) or parts["axial"].shape != (ne,):
            raise SceneError(f"{path}: element_frame (ne, 3, 3), element_length and element_axial (ne,) are needed")
        inertia = {}
        if "element_line_mass" in data or "element_polar_mass" in data:
            for k in ("line_mass", "polar_mass"):
                v = np.asarray(data.get(f"element_{k}", np.zeros(0)), float)
                if v.shape != (ne,):
                    raise SceneError(f"{path}: element_line_mass and element_polar_mass must both be (ne,) = ({ne},)")
                inertia[k] = jnp.asarray(v)
        elements = Elements(
            frame=jnp.asarray(parts["frame"]),
            length=jnp.asarray(parts["length"]),
            axial=jnp.asarray(parts["axial"]),
            nodes=tuple((int(a), int(b)) for a, b in en),
            **inertia,
        )
    if "plate_nodes" in data:
        pn = np.asarray(data["plate_nodes"], np.int64)
        if pn.ndim != 2 or pn.shape[1] != 4 or pn.min(initial=0) < 0 or pn.max(initial=0) >= nodes.shape[0]:
            raise SceneError(f"{path}: plate_nodes must be (ne, 4) node indices")
        keys = ("normal", "axes", "dN", "weights", "membrane")
        missing = [f"plate_{k}" for k in keys if f"plate_{k}" not in data]
        if missing:
            raise SceneError(f"{path}: plate elements need {', '.join(missing)}")
        elements = PlateElements(
            **{k: jnp.asarray(np.asarray(data[f"plate_{k}"], float)) for k in keys},
            nodes=tuple(tuple(int(i) for i in q) for q in pn),
        )
    return FEModel(jnp.asarray(M), jnp.asarray(K), jnp.asarray(nodes), elements, dofs)


def read_matrix_market(mass_path, stiffness_path, nodes, dofs: int = 6) -> FEModel:
    """An :class:`FEModel` from a mass and a stiffness matrix in MatrixMarket files (``.mtx``, as
    Abaqus' and ANSYS' matrix exports are converted to; read by ``scipy.io.mmread``, symmetric
    storage mirrored) and the node table `nodes` (n_nodes, 3; degrees of freedom node by node).
    Without element data the geometric stiffness is not available (``appendage(...,
    geometric=False)``)."""
    try:
        import scipy.io
    except ImportError:
        raise ImportError("read_matrix_market reads MatrixMarket files with scipy: pip install scipy") from None

    import inspect

    nodes = np.asarray(nodes, float)
    N = dofs * nodes.shape[0]
    mats = []
    # newer scipy takes the sparse kind (`spmatrix`: its default changes in scipy 1.20, and 1.18
    # warns until then); either kind is made dense below
    kind = {"spmatrix": False} if "spmatrix" in inspect.signature(scipy.io.mmread).parameters else {}
    for name, p in (("mass", mass_path), ("stiffness", stiffness_path)):
        try:
            A = scipy.io.mmread(str(p), **kind)
        except (OSError, ValueError) as exc:
            raise SceneError(f"{p}: not a readable MatrixMarket file ({exc})") from None
        dense = getattr(A, "toarray", None)
        A = np.asarray(dense() if dense is not None else A, float)
        mats.append(_matrix({name: A}, name, N, p))
    return FEModel(jnp.asarray(mats[0]), jnp.asarray(mats[1]), jnp.asarray(nodes), None, dofs)


def read_op4(path) -> dict[str, np.ndarray]:
    """The matrices of a NASTRAN OP4 file (``OUTPUT4``), by name: its text form (FORMATTED) or
    its binary form (the default: Fortran unformatted records, either byte order).

    The format (MSC Nastran DMAP guide, OUTPUT4): for each matrix a header ``NCOL NROW NF NTYPE
    NAME`` (the form NF: 1 square, 2 rectangular, 6 symmetric, ...; NTYPE 1 or 2: real single or
    double precision; the text form adds a Fortran format such as ``1P,3E23.16``), then columns as
    records ``ICOL IROW NW`` followed by the values from row IROW (NW values in the text form, NW
    four-byte words in the binary one), and a closing record with ``ICOL = NCOL + 1``. Every
    column holds its rows in full (symmetric matrices too). Sparse columns (``IROW = 0``, or
    BIGMAT, ``NROW < 0``) and complex matrices are refused with the reason. pyNastran reads the
    same files, but its releases require numpy < 2, which jaxtree's JAX cannot import beside; this
    reader is the format's dense real case, written here.
    """
    import re

    try:
        raw = pathlib.Path(path).read_bytes()
    except OSError as exc:
        raise SceneError(f"{path}: cannot read ({exc})") from None
    if len(raw) >= 4 and 24 in (int.from_bytes(raw[:4], "little"), int.from_bytes(raw[:4], "big")):
        return _op4_binary(path, raw)
    try:
        lines = raw.decode().splitlines()
    except UnicodeDecodeError:
        raise SceneError(
            f"{path}: neither a text OP4 file nor a binary one (its first record is not a header)"
        ) from None
    out: dict[str, np.ndarray] = {}
    i = 0
    while i < len(lines):
        head = lines[i]
        i += 1
        if not head.strip():
            continue
        fields = head[:32].split()
        m = re.search(r"(\d+)\s*[EDed](\d+)\.(\d+)", head[40:])
        if len(fields) < 4 or m is None:
            raise SceneError(f"{path}, line {i}: not an OP4 matrix header: {head.strip()!r}")
        ncol, nrow, form, ntype = (int(x) for x in fields[:4])
        name = head[32:40].strip() or f"matrix{len(out) + 1}"
        if nrow < 0:
            raise SceneError(f"{path}: {name} is stored sparse (BIGMAT); write it dense")
        if ntype not in (1, 2):
            raise SceneError(f"{path}: {name} has NTYPE {ntype} (complex); jaxtree reads real matrices")
        per, width = int(m.group(1)), int(m.group(2))
        A = np.zeros((nrow, ncol))
        while True:
            if i >= len(lines):
                raise SceneError(f"{path}: {name} ends before its closing record")
            rec = lines[i].split()
            i += 1
            col = int(rec[0])
            if col > ncol:  # the closing record, followed by its one value
                i += 1 if len(rec) >= 3 and int(rec[2]) > 0 else 0
                break
            row, nw = int(rec[1]), int(rec[2])
            values: list[float] = []
            while len(values) < nw:
                text = lines[i].replace("D", "E").replace("d", "e")
                i += 1
                values += [
                    float(text[k : k + width])
                    for k in range(0, min(len(text), per * width), width)
                    if text[k : k + width].strip()
                ]
            if row < 1 or row - 1 + nw > nrow or not 1 <= col <= ncol:
                raise SceneError(f"{path}: {name}: column {col} from row {row} ({nw} values) outside {nrow} x {ncol}")
            A[row - 1 : row - 1 + nw, col - 1] = values[:nw]
        if form == 6 and nrow == ncol and not np.allclose(A, A.T, rtol=1e-12, atol=0.0):
            raise SceneError(f"{path}: {name} is declared symmetric (form 6) but is not")
        out[name] = A
    return out


def _op4_binary(path, raw: bytes) -> dict[str, np.ndarray]:
    """:func:`read_op4` of a binary file: Fortran sequential records (a four-byte length before
    and after each), the first of each matrix its 24-byte header, whose length gives the byte
    order."""
    order = "<" if int.from_bytes(raw[:4], "little") == 24 else ">"
    pos = 0

    def record(what: str) -> bytes:
        nonlocal pos
        if pos + 4 > len(raw):
            raise SceneError(f"{path}: the file ends inside {what}")
        n = int(np.frombuffer(raw, f"{order}i4", 1, pos)[0])
        end = pos + 4 + n
        if n < 0 or end + 4 > len(raw) or int(np.frombuffer(raw, f"{order}i4", 1, end)[0]) != n:
            raise SceneError(f"{path}: a broken record in {what} at byte {pos}")
        body = raw[pos + 4 : end]
        pos = end + 4
        return body

    out: dict[str, np.ndarray] = {}
    while pos < len(raw):
        head = record("a matrix header")
        if len(head) != 24:
            raise SceneError(f"{path}: not an OP4 matrix header at byte {pos - len(head) - 8} ({len(head)} bytes)")
        ncol, nrow, form, ntype = (int(x) for x in np.frombuffer(head, f"{order}i4", 4))
        name = head[16:24].decode("ascii", "replace").strip() or f"matrix{len(out) + 1}"
        if nrow < 0:
            raise SceneError(f"{path}: {name} is stored sparse (BIGMAT); write it dense")
        if ntype not in (1, 2):
            raise SceneError(f"{path}: {name} has NTYPE {ntype} (complex); jaxtree reads real matrices")
        kind, per = (f"{order}f4", 1) if ntype == 1 else (f"{order}f8", 2)
        A = np.zeros((nrow, ncol))
        while True:
            rec = record(f"{name}'s columns")
            if len(rec) < 12:
                raise SceneError(f"{path}: {name}: a column record of {len(rec)} bytes")
            col, row, nw = (int(x) for x in np.frombuffer(rec, f"{order}i4", 3))
            if col > ncol:  # the closing record
                break
            if row == 0:
                raise SceneError(f"{path}: {name} is stored sparse (IROW = 0 strings); write it dense")
            count = nw // per
            if row < 1 or row - 1 + count > nrow or not 1 <= col <= ncol or len(rec) < 12 + 4 * nw:
                raise SceneError(
                    f"{path}: {name}: column {col} from row {row} ({count} values) outside {nrow} x {ncol}"
                )
            A[row - 1 : row - 1 + count, col - 1] = np.frombuffer(rec, kind, count, 12)
        if form == 6 and nrow == ncol and not np.allclose(A, A.T, rtol=1e-12, atol=0.0):
            raise SceneError(f"{path}: {name} is declared symmetric (form 6) but is not")
        out[name] = A
    return out


def save_appendage(path, ap: Appendage) -> None:
    """Write `ap`'s modes and invariants (``jaxtree-appendage/1``), atomically."""
    arrays = {k: np.asarray(getattr(ap, k)) for k in _ARRAYS}
    arrays.update({k: np.asarray(getattr(ap.terms, k)) for k in _TERMS})
    arrays.update(
        format=np.asarray(APPENDAGE_FORMAT),
        interface=np.asarray(ap.interface, np.int64),
        outputs=np.asarray(ap.outputs, np.int64),
        dofs=np.asarray(ap.dofs),
        geometric=np.asarray(ap.geometric),
        body=np.asarray(ap.body),
        name=np.asarray(ap.name),
        edges=np.asarray(ap.edges, np.int64).reshape(-1, 2),
    )
    _write(path, arrays)


def load_appendage(path) -> Appendage:
    """Read an appendage written by :func:`save_appendage`."""
    data = _open(path, APPENDAGE_FORMAT)
    missing = [k for k in (*_ARRAYS, *_TERMS, "interface", "outputs", "dofs", "body") if k not in data]
    if missing:
        raise SceneError(f"{path}: missing {', '.join(missing)}")
    body = data["body"]
    body = int(body) if np.issubdtype(body.dtype, np.integer) else str(body)
    terms = Terms(*(jnp.asarray(data[k]) for k in _TERMS), mass=jnp.asarray(data["mass"]))
    return Appendage(
        **{k: jnp.asarray(data[k]) for k in _ARRAYS},
        terms=terms,
        body=body,
        interface=tuple(int(i) for i in data["interface"]),
        outputs=tuple(int(i) for i in data["outputs"]),
        dofs=int(data["dofs"]),
        geometric=bool(data.get("geometric", True)),
        name=str(data.get("name", "")),
        edges=tuple(
            (int(a), int(b)) for a, b in np.asarray(data.get("edges", np.zeros((0, 2))), np.int64).reshape(-1, 2)
        ),
    )
