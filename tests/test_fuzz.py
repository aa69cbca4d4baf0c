"""Property-based fuzzing of the input checks (hypothesis, derandomized: the same examples on
every run, so CI is reproducible).

Each test starts from a valid input -- a random tree scene that must build without a warning,
a dispersed batch of fig4, a valid call -- and breaks one thing in it: a wrong type or shape, a
negative, zero or non-finite value, a cycle or a parent out of order, a non-symmetric or
indefinite inertia or one that violates the triangle inequality, a zero or non-finite axis, a
missing field, an unknown joint kind, a spring on a massless branch, a wrong initial-state
length, an unknown key. The input must then be rejected with :class:`jaxtree.SceneError` whose
message names the body (or run, or argument) and the field that was broken -- never an exception
from inside JAX or numpy -- and before anything is traced (no jaxpr trace is recorded). A key of
the user's own (``x-`` prefix) loads silently.
"""

import contextlib
import copy
import math
import re
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import jaxtree
from jaxtree import Body, SceneError, SceneWarning

ULPS = 1e-15  # an axis with huge entries, normalized without overflow, against 2**-0.5: a few ulps

FUZZ = settings(
    derandomize=True,
    database=None,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.function_scoped_fixture],
)


def fuzz(examples):
    return settings(FUZZ, max_examples=examples)


_TRACES = []
jax.monitoring.register_event_duration_secs_listener(
    lambda event, duration, **kw: _TRACES.append(event) if event == "/jax/core/compile/jaxpr_trace_duration" else None
)


@contextlib.contextmanager
def no_tracing():
    """Fail if JAX traces anything inside (the checks run on plain numpy data)."""
    before = len(_TRACES)
    yield
    assert len(_TRACES) == before, "the input was traced before it was rejected"


def rejected(fn, *fragments):
    """`fn()` raises SceneError (ours, not JAX's or numpy's) naming every fragment (regexes)."""
    with no_tracing(), warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        with pytest.raises(SceneError) as err:
            fn()
    message = str(err.value)
    for f in fragments:
        assert re.search(f, message), (f, message)
    return message


# ----------------------------------------------------------------------------- valid scenes
def _box(m, a, b, c):
    return np.diag([m * (b * b + c * c) / 12, m * (a * a + c * c) / 12, m * (a * a + b * b) / 12])


@st.composite
def scenes(draw, max_bodies=7):
    """A valid jaxtree-scene/1 document: a random tree of 2..max_bodies bodies, boxes of random
    size turned arbitrarily, unit axes, free, sprung and prescribed hinges, massless frames.
    Hypothesis draws the size and a seed; numpy draws the numbers (a hundred hypothesis draws
    per scene would cost most of the test's time)."""
    nb = draw(st.integers(2, max_bodies))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    bodies = []
    for k in range(nb):
        massless = k > 0 and rng.random() < 0.25
        m = 0.0 if massless else float(rng.uniform(0.1, 100.0))
        q = rng.normal(size=4)
        w, x, y, z = q / np.linalg.norm(q)
        R = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
        J = R @ _box(m, *rng.uniform(0.05, 3.0, 3)) @ R.T
        d = {
            "name": f"b{k}_{rng.choice(['hub', 'arm', 'rotor', 'panel'])}",
            "mass": m,
            "inertia": (0.5 * (J + J.T)).tolist(),
        }
        if k > 0:
            axis = rng.normal(size=3)
            d.update(
                parent=int(rng.integers(0, k)),
                axis=(axis / np.linalg.norm(axis)).tolist(),
                hinge_on_parent=rng.uniform(-1, 1, 3).tolist(),
                hinge_on_body=rng.uniform(-1, 1, 3).tolist(),
                joint={"kind": "free"},
            )
        bodies.append(d)
    heavy = [any(bodies[j]["mass"] > 0 for j in _subtree(bodies, k)) for k in range(nb)]
    for k in range(1, nb):
        kind = rng.choice(["free", "spring_damper", "prescribed"])
        if kind == "spring_damper" and heavy[k]:
            bodies[k]["joint"] = {
                "kind": "spring_damper",
                "stiffness": float(rng.uniform(0, 500)),
                "damping": float(rng.uniform(0, 5)),
            }
        elif kind == "prescribed":
            A, W, P = rng.uniform([-1, 0, -3], [1, 3, 3])
            bodies[k]["joint"] = {
                "kind": "prescribed",
                "function": "sine",
                "amplitude": float(A),
                "frequency": float(W),
                "phase": float(P),
            }
    n = nb - 1
    initial = {
        "gamma": rng.uniform(-3, 3, n).tolist(),
        "gamma_dot": rng.uniform(-3, 3, n).tolist(),
        "omega0": rng.uniform(-1, 1, 3).tolist(),
        "attitude_dcm": np.eye(3).tolist(),
    }
    return {"format": "jaxtree-scene/1", "name": "fuzz", "description": "", "bodies": bodies, "initial": initial}


def _subtree(bodies, k):
    out = [k]
    for j in range(k + 1, len(bodies)):
        if bodies[j].get("parent") in out:
            out.append(j)
    return out


def build(doc, builder):
    """Build the document as JSON data (scene_from_dict) or through the Python builder (Body
    records, numpy arrays)."""
    if not builder:
        return jaxtree.scene_from_dict(doc)
    bodies = [
        Body(**{k: (_array(v) if isinstance(v, list) and k != "name" else v) for k, v in b.items()})
        for b in doc["bodies"]
    ]
    return jaxtree.build_model(bodies, doc.get("initial"), name=doc.get("name", ""))


def _array(v):
    try:
        return np.asarray(v)
    except ValueError:  # a ragged list stays a list
        return v


# ----------------------------------------------------------------------------- malformations
BAD_TYPES = [None, True, "1.0", "abc", {"x": 1}, 1 + 2j, [[1.0, 2.0], [3.0]], 10**400, object()]
NONFINITE = [math.nan, math.inf, -math.inf]


@st.composite
def malformed(draw):
    """``(doc, body, fields, builder)``: a valid scene broken in one place; the error must name
    `body` (an index, or None for the initial state / the document) and all of `fields`."""
    doc = draw(scenes())
    builder = draw(st.booleans())
    bodies = doc["bodies"]
    nb = len(bodies)
    k = draw(st.integers(0, nb - 1))
    b = bodies[k]
    hinge = k > 0
    what = draw(
        st.sampled_from(
            [
                "type",
                "shape",
                "nonfinite",
                "negative_mass",
                "inertia_asymmetric",
                "inertia_indefinite",
                "inertia_triangle",
                "massless_inertia",
                "axis_zero",
                "axis_nonfinite",
                "parent_self",
                "parent_later",
                "parent_negative",
                "parent_name_later",
                "parent_unknown",
                "parent_float",
                "missing",
                "joint_kind",
                "joint_no_kind",
                "joint_missing",
                "joint_negative",
                "joint_nonfinite",
                "massless_spring",
                "duplicate_name",
                "reference_hinge",
                "initial_length",
                "initial_nonfinite",
                "initial_type",
                "initial_dcm",
                "all_massless",
                "name_type",
            ]
        )
    )
    fields = hinge_fields = ["axis", "hinge_on_parent", "hinge_on_body"]
    numeric = ["mass", "inertia"] + (hinge_fields if hinge else [])
    if what == "type":
        f = draw(st.sampled_from(numeric))
        b[f] = draw(st.sampled_from(BAD_TYPES))
        if b[f] is None:
            what = "missing"
        fields = [f]
    elif what == "shape":
        f = draw(st.sampled_from(numeric))
        shape = draw(st.sampled_from([(), (2,), (4,), (3, 3), (2, 3), (3, 3, 1), (0,)]))
        if f == "inertia" and shape == (3, 3) or f != "inertia" and f != "mass" and shape == (3,):
            shape = (2,)
        if f == "mass" and shape == ():
            shape = (1,)
        b[f] = np.ones(shape).tolist()
        fields = [f]
    elif what == "nonfinite":
        f = draw(st.sampled_from(numeric))
        bad = draw(st.sampled_from(NONFINITE))
        if f == "mass":
            b[f] = bad
        else:
            a = np.asarray(b[f], float)
            a.flat[draw(st.integers(0, a.size - 1))] = bad
            b[f] = a.tolist()
        fields = [f]
    elif what == "negative_mass":
        b["mass"] = -draw(st.floats(1e-9, 1e6))
        fields = ["mass"]
    elif what in ("inertia_asymmetric", "inertia_indefinite", "inertia_triangle"):
        b["mass"] = max(b["mass"], 1.0)
        J = np.diag([2.0, 3.0, 4.0])
        if what == "inertia_asymmetric":
            J[0, 1] += draw(st.floats(0.01, 5.0))
        elif what == "inertia_indefinite":
            J[draw(st.integers(0, 2))] *= -1
        else:
            J = np.diag([1.0, 2.0, 3.0 + draw(st.floats(0.01, 100.0))])
        b["inertia"] = J.tolist()
        fields = ["inertia"]
    elif what == "massless_inertia":
        b["mass"] = 0.0
        b["inertia"] = np.diag([1.0, 1.0, 1.5]).tolist()
        fields = ["inertia"]
    elif what in ("axis_zero", "axis_nonfinite") and hinge:
        b["axis"] = [0.0, 0.0, 0.0] if what == "axis_zero" else [0.0, draw(st.sampled_from(NONFINITE)), 1.0]
        fields = ["axis"]
    elif what.startswith("parent") and hinge:
        b["parent"] = {
            "parent_self": k,
            "parent_later": nb + draw(st.integers(0, 3)),
            "parent_negative": -1,
            "parent_name_later": bodies[-1]["name"] if k < nb - 1 else k,
            "parent_unknown": "nowhere",
            "parent_float": 0.5,
        }[what]
        fields = ["parent"]
    elif what == "missing":
        f = draw(st.sampled_from(["name", "mass", "inertia"] + (hinge_fields + ["parent"] if hinge else [])))
        if builder and f in ("name", "mass", "inertia"):
            b[f] = None  # Body requires them: give None instead
        else:
            del b[f]
        fields = [f]
    elif what.startswith("joint") and hinge:
        if what == "joint_kind":
            b["joint"] = {"kind": draw(st.sampled_from(["ball", "slider", "", 3, None, "Free"]))}
        elif what == "joint_no_kind":
            b["joint"] = {"stiffness": 1.0}
        elif what == "joint_missing":
            b["joint"] = draw(
                st.sampled_from(
                    [
                        {"kind": "spring_damper", "damping": 1.0},
                        {"kind": "prescribed", "function": "sine", "frequency": 1.0},
                        {"kind": "prescribed", "function": "sine", "amplitude": 1.0},
                        {"kind": "prescribed", "function": "cosine", "amplitude": 1.0, "frequency": 1.0},
                        {"kind": "prescribed", "amplitude": 1.0, "frequency": 1.0},
                    ]
                )
            )
        elif what == "joint_negative":
            b["mass"] = max(b["mass"], 1.0)
            b["inertia"] = np.diag([1.0, 1.0, 1.5]).tolist()
            key = draw(st.sampled_from(["stiffness", "damping"]))
            b["joint"] = {"kind": "spring_damper", "stiffness": 1.0, "damping": 0.1, key: -draw(st.floats(1e-6, 1e3))}
        else:
            key = draw(st.sampled_from(["stiffness", "damping", "amplitude", "frequency", "phase"]))
            bad = draw(st.sampled_from(NONFINITE + BAD_TYPES[1:]))
            if key in ("stiffness", "damping"):
                b["mass"] = max(b["mass"], 1.0)
                b["inertia"] = np.diag([1.0, 1.0, 1.5]).tolist()
                b["joint"] = {"kind": "spring_damper", "stiffness": 1.0, "damping": 0.1, key: bad}
            else:
                b["joint"] = {"kind": "prescribed", "function": "sine", "amplitude": 1.0, "frequency": 1.0, key: bad}
        fields = ["joint"]
    elif what == "massless_spring" and hinge:
        for j in _subtree(bodies, k):
            bodies[j]["mass"], bodies[j]["inertia"] = 0.0, np.zeros((3, 3)).tolist()
            if j != k and bodies[j]["joint"]["kind"] == "spring_damper":
                bodies[j]["joint"] = {"kind": "free"}
        for j in range(1, k):  # an ancestor left with only massless bodies outboard loses its spring
            if bodies[j]["joint"]["kind"] == "spring_damper" and all(
                bodies[i]["mass"] == 0 for i in _subtree(bodies, j)
            ):
                bodies[j]["joint"] = {"kind": "free"}
        b["joint"] = {"kind": "spring_damper", "stiffness": 10.0}
        if sum(x["mass"] for x in bodies) == 0:
            bodies[0]["mass"], bodies[0]["inertia"] = 1.0, np.eye(3).tolist()
        fields = ["joint"]
    elif what == "duplicate_name" and hinge:
        b["name"] = bodies[draw(st.integers(0, k - 1))]["name"]
        fields = ["name"]
    elif what == "reference_hinge":
        k, b = 0, bodies[0]
        f = draw(st.sampled_from(["parent", "axis", "hinge_on_parent", "joint"]))
        b[f] = {
            "parent": 0,
            "axis": [0.0, 0.0, 1.0],
            "hinge_on_parent": [0.0, 0.0, 0.0],
            "joint": {"kind": "spring_damper", "stiffness": 1.0},
        }[f]
        fields = [f]
    elif what == "name_type":
        b["name"] = draw(st.sampled_from([3, None, "", ["a"], 1.5]))
        fields = ["name"]
    elif what == "all_massless":
        for x in bodies:
            x["mass"], x["inertia"] = 0.0, np.zeros((3, 3)).tolist()
            if "joint" in x:
                x["joint"] = {"kind": "free"}
        k, fields = None, ["mass"]
    elif what.startswith("initial"):
        n = nb - 1
        f = draw(st.sampled_from(["gamma", "gamma_dot", "omega0", "attitude_dcm"]))
        length = n if f.startswith("gamma") else 3
        if what == "initial_length" or (what == "initial_dcm" and f != "attitude_dcm"):
            bad_len = draw(st.sampled_from([length - 1, length + 1, length + 5]))
            doc["initial"][f] = np.zeros(bad_len).tolist() if f != "attitude_dcm" else np.eye(bad_len).tolist()
        elif what == "initial_nonfinite":
            a = np.asarray(doc["initial"][f], float)
            a.flat[draw(st.integers(0, a.size - 1))] = draw(st.sampled_from(NONFINITE))
            doc["initial"][f] = a.tolist()
        elif what == "initial_type":
            doc["initial"][f] = draw(st.sampled_from(BAD_TYPES[1:]))
        else:
            doc["initial"][f] = draw(
                st.sampled_from([np.diag([1.0, 1.0, -1.0]), 1.01 * np.eye(3), np.ones((3, 3))])
            ).tolist()
        k, fields = None, ["initial", f]
    else:
        # an option that does not apply to the reference body: a non-numeric mass instead
        b["mass"] = draw(st.sampled_from(BAD_TYPES[1:] + NONFINITE + [-1.0]))
        fields = ["mass"]
    return doc, k, fields, builder, what


@fuzz(60)
@given(scenes(), st.booleans())
def test_random_valid_scenes_build_without_warnings(doc, builder):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = build(doc, builder)
    assert model.n == len(doc["bodies"]) - 1


@fuzz(1200)
@given(malformed())
def test_malformed_scenes_are_rejected_naming_body_and_field(case):
    doc, k, fields, builder, what = case
    event(what)
    message = rejected(lambda: build(doc, builder))
    if k is not None:
        assert re.search(rf"\bbody {k}\b", message), (k, message)
    assert all(f in message for f in fields), (fields, message)


@fuzz(150)
@given(
    scenes(),
    st.sampled_from(["body", "joint", "initial", "scene"]),
    st.text("abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=12),
    st.data(),
)
def test_unknown_keys_are_refused_naming_the_key_and_its_place(doc, where, key, data):
    if key in {
        "name",
        "mass",
        "inertia",
        "parent",
        "axis",
        "hinge_on_parent",
        "hinge_on_body",
        "joint",
        "kind",
        "stiffness",
        "damping",
        "function",
        "amplitude",
        "frequency",
        "phase",
        "gamma",
        "gamma_dot",
        "omega0",
        "dcm",
        "attitude_dcm",
        "format",
        "description",
        "bodies",
        "initial",
    }:
        key = key + "_x"
    k = data.draw(st.integers(1, len(doc["bodies"]) - 1))
    target = {"body": doc["bodies"][k], "joint": doc["bodies"][k]["joint"], "initial": doc["initial"], "scene": doc}[
        where
    ]
    target[key] = 1.0
    message = rejected(lambda: jaxtree.scene_from_dict(doc), re.escape(f"unknown key {key!r}"))
    if where in ("body", "joint"):
        assert re.search(rf"\bbody {k}\b", message), message
    # the same key as one of the user's own ("x-" prefix) is read past: the scene loads, silently
    # (no no_tracing() here: loading converts the scene's arrays to JAX arrays, eagerly)
    target["x-" + key] = target.pop(key)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        jaxtree.scene_from_dict(doc)


@fuzz(60)
@given(
    st.sampled_from(
        [
            None,
            3,
            "x",
            [1, 2],
            {"format": "other"},
            {"format": "jaxtree-scene/1"},
            {"format": "jaxtree-scene/1", "bodies": {}},
            {"format": "jaxtree-scene/1", "bodies": []},
            {"format": "jaxtree-scene/1", "bodies": [3]},
            {
                "format": "jaxtree-scene/1",
                "bodies": [{"name": "a", "mass": 1, "inertia": np.eye(3).tolist()}],
                "initial": [1, 2],
            },
            {
                "format": "jaxtree-scene/1",
                "bodies": [{"name": "a", "mass": 1, "inertia": np.eye(3).tolist()}],
                "name": 5,
            },
        ]
    )
)
def test_malformed_documents_are_rejected(doc):
    rejected(lambda: jaxtree.scene_from_dict(copy.deepcopy(doc)), r"scene|bod|initial|name")


def test_builder_arguments_are_checked():
    ok = [Body("hub", 10.0, np.eye(3)), Body("arm", 1.0, np.eye(3), 0, [0, 0, 1], [1, 0, 0], [0, 0, 0])]
    rejected(lambda: jaxtree.build_model(None), "bodies")
    rejected(lambda: jaxtree.build_model("hub"), "bodies")
    rejected(lambda: jaxtree.build_model(ok, name=3), "name")
    rejected(lambda: jaxtree.build_model(ok, [0.0]), "initial")
    rejected(
        lambda: jaxtree.build_model(ok, jaxtree.State(np.eye(3), np.zeros(3), np.zeros(2), np.zeros(1))),
        "initial",
        "'gamma'",
        "length 1",
    )
    rejected(lambda: jaxtree.build_model(ok, loads=object()), "loads")
    arm = Body("arm", 1.0, np.eye(3), 0, [0, 0, 1], [1, 0, 0], [0, 0, 0], jaxtree.SpringDamper("stiff"))
    rejected(lambda: jaxtree.build_model([ok[0], arm]), r"body 1\b", "joint.stiffness")
    arm = Body("arm", 1.0, np.eye(3), 0, [0, 0, 1], [1, 0, 0], [0, 0, 0], jaxtree.Prescribed(3.0))
    rejected(lambda: jaxtree.build_model([ok[0], arm]), r"body 1\b", "joint.fn")
    arm = Body("arm", 1.0, np.eye(3), 0, jnp.asarray([0.0, 0.0, 1e300]) * 1e300, [1, 0, 0], [0, 0, 0])
    rejected(lambda: jaxtree.build_model([ok[0], arm]), r"body 1\b", "'axis'")
    huge = Body("arm", 1.0, np.eye(3), 0, [1e300, 1e300, 0.0], [1, 0, 0], [0, 0, 0])  # normalizes without overflow
    np.testing.assert_allclose(jaxtree.build_model([ok[0], huge]).axis[0], [2**-0.5, 2**-0.5, 0.0], rtol=ULPS)


# ----------------------------------------------------------------------------- dispersed batches
@pytest.fixture(scope="module")
def fig4():
    return jaxtree.load_scene("fig4")


BATCH_FAULTS = {
    # leaf, body offset (hinge leaves are indexed by hinge k - 1), the field named, and the fault
    "mass_nan": ("mass", 0, "'mass'", lambda x, rng: np.nan),
    "mass_negative": ("mass", 0, "'mass'", lambda x, rng: -rng.uniform(0.1, 10)),
    "inertia_nan": (
        "inertia",
        0,
        "'inertia'",
        lambda x, rng: np.where(np.arange(9).reshape(3, 3) == rng.integers(9), rng.choice([np.nan, np.inf]), x),
    ),
    "inertia_asymmetric": (
        "inertia",
        0,
        "'inertia'",
        lambda x, rng: x + np.triu(np.full((3, 3), rng.uniform(0.5, 5)), 1),
    ),
    "inertia_indefinite": ("inertia", 0, "'inertia'", lambda x, rng: np.diag([1.0, -rng.uniform(0.1, 2), 1.5])),
    "inertia_triangle": ("inertia", 0, "'inertia'", lambda x, rng: np.diag([1.0, 1.0, 2.0 + rng.uniform(0.01, 5)])),
    "axis_not_unit": ("axis", 1, "'axis'", lambda x, rng: x * rng.uniform(1.01, 3)),
    "axis_nan": ("axis", 1, "'axis'", lambda x, rng: np.array([np.nan, 0, 1.0])),
    "hinge_inf": ("hinge_on_parent", 1, "'hinge_on_parent'", lambda x, rng: np.array([0, np.inf, 0.0])),
    "stiffness_negative": ("stiffness", 1, "'joint.stiffness'", lambda x, rng: -rng.uniform(1, 100)),
    "damping_nan": ("damping", 1, "'joint.damping'", lambda x, rng: np.nan),
}


@fuzz(250)
@given(st.sampled_from(sorted(BATCH_FAULTS)), st.integers(1, 6), st.data())
def test_dispersed_batches_are_rejected_naming_run_body_and_field(fig4, fault, runs, data):
    leaf, offset, field, corrupt = BATCH_FAULTS[fault]
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    values = np.tile(np.asarray(getattr(fig4, leaf)), (runs,) + (1,) * getattr(fig4, leaf).ndim)
    mass = np.tile(np.asarray(fig4.mass), (runs, 1)) * rng.uniform(0.95, 1.05, (runs, fig4.n + 1))
    massive = list(fig4.massive)
    candidates = {
        "mass": massive,
        "inertia": [k for k in massive],
        "stiffness": [k for k in fig4.sprung],
        "damping": [k for k in fig4.sprung],
    }.get(leaf, list(range(1, fig4.n + 1)))
    k = data.draw(st.sampled_from(candidates))
    r = data.draw(st.integers(0, runs - 1))
    values[r, k - offset] = corrupt(values[r, k - offset], rng)
    mass[:, [k for k in range(fig4.n + 1) if k not in massive]] = 0.0
    leaves = {"mass": mass, leaf: values} if leaf != "mass" else {"mass": values}
    batch = eqx.tree_at(
        lambda m: tuple(getattr(m, f) for f in leaves), fig4, tuple(jnp.asarray(v) for v in leaves.values())
    )
    rejected(lambda: jaxtree.validate_model(batch), rf"^run \({r},\): body {k} ", field)


def test_validate_model_rejects_leaves_of_the_wrong_kind(fig4):
    rejected(lambda: jaxtree.validate_model("fig4"), "Model")
    bad = {  # the model with one leaf replaced, and what the error names
        "integer mass": (lambda m: m.mass, jnp.arange(11), ["'mass'", "floating"]),
        "list axis": (lambda m: m.axis, [[0, 0, 1]] * 10, ["'axis'"]),
        "axis shape": (lambda m: m.axis, jnp.ones((4, 9, 3)), ["'axis'", "shape"]),
        "initial gamma": (lambda m: m.initial.gamma, jnp.full(10, jnp.nan), ["initial.gamma", "finite"]),
        "initial dcm": (lambda m: m.initial.dcm, 2 * jnp.eye(3), ["initial.dcm", "rotation"]),
        "frequency": (lambda m: m.prescription.frequency, jnp.asarray([jnp.inf]), [r"body 1\b", "joint.frequency"]),
    }
    for where, value, fragments in bad.values():
        model = eqx.tree_at(where, fig4, value)
        rejected(lambda: jaxtree.validate_model(model), *fragments)
    with pytest.raises(TypeError, match="concrete arrays"):  # a SceneError that is also a TypeError
        jax.jit(lambda m: jaxtree.validate_model(m).mass)(fig4)


# ----------------------------------------------------------------------------- function arguments
@pytest.fixture(scope="module")
def small():
    return jaxtree.load_scene("appendix_c")  # n = 2, no prescribed hinge


SIMULATE_BAD = {
    "t1": ["1", None, [1.0, 2.0], math.nan, math.inf, True, {"t": 1}],
    "t0": ["0", math.nan, -math.inf, [0.0]],
    "saveat": ["abc", [0.0, "a"], [[0.0, 1.0]], 1, 0, -4, [0.0, 2.0, 1.0], [0.0, 5.0], [math.nan, 1.0]],
    "rtol": ["x", -1e-6, math.nan, [1e-6, "a"], math.inf],
    "atol": ["x", -1.0, [math.nan]],
    "max_steps": [0, -3, 2.5, "100", None, math.nan],
    "dt0": [-0.1, "x", math.nan, [0.1, 0.2]],
    "attitude": ["foo", 3, None],
    "translation": [(1,), ([1, 2], [0, 0, 0]), ([0, 0, 0], "x"), "yes", 2, (1, 2, 3)],
    "solver": ["dopri8", 3],
    "stepsize_controller": ["pid"],
    "adjoint": ["backsolve"],
    "event": [3, "stop"],
    "progress": ["yes", 3],
    "law": [3, "pd"],
    "controller": [3, "pid"],
    "throw": ["no", None],
    "y0": [3, "state", (np.eye(3), np.zeros(3), np.zeros(2), np.zeros(2))],
    "y0.gamma": [np.zeros(3), "ab", np.zeros((2, 1))],
    "y0.omega0": [np.zeros(2), None],
    "y0.dcm": [2 * np.eye(3), np.diag([1.0, 1.0, -1.0]), np.eye(2), [["a"] * 3] * 3],
}


@fuzz(250)
@given(st.sampled_from(sorted(SIMULATE_BAD)), st.data())
def test_bad_simulate_arguments_are_named_before_tracing(small, argument, data):
    value = data.draw(st.sampled_from(SIMULATE_BAD[argument]))
    kwargs = {}
    t1 = 1.0
    if argument == "t1":
        t1 = value
    elif argument.startswith("y0."):
        field = argument[3:]
        kwargs["y0"] = small.initial._replace(**{field: value})
    else:
        kwargs[argument] = value
    name = argument.split(".")[0]
    rejected(lambda: jaxtree.simulate(small, t1, **kwargs), "simulate", rf"\b{name}\b")


LINEARIZE_BAD = {
    "small": [(), (0,), (3,), ("nope",), (True,), (1, 1), (1, "rod_plus"), 1.5, [None]],
    "omega0": ["x", [0.0, 1.0], [0.0, math.nan, 0.0], [[0.0, 0.0, 0.0]]],
    "gamma": [[0.0], "ab", [math.inf, 0.0], [True, False]],
    "dcm": [np.eye(2), 2 * np.eye(3), np.diag([1.0, -1.0, 1.0]), "eye"],
    "t": [math.nan, "0", [0.0, 1.0]],
    "model": ["appendix_c", None, 3],
}


@fuzz(150)
@given(
    st.sampled_from(["linearize", "linearize_vehicle", "hybrid_model"]),
    st.sampled_from(sorted(LINEARIZE_BAD)),
    st.data(),
)
def test_bad_linearize_and_hybrid_arguments_are_named_before_tracing(small, fn, argument, data):
    value = data.draw(st.sampled_from(LINEARIZE_BAD[argument]))
    if argument == "t" and fn == "hybrid_model":
        argument, value = "cutoff", data.draw(st.sampled_from(["x", -1.0, math.nan]))
    kwargs = {"small": (1, 2)} if fn != "linearize_vehicle" else {}
    if argument == "small" and value == ():
        value = []  # an empty set A (linearize_vehicle takes None for all hinges)
    kwargs[argument] = value
    model = kwargs.pop("model", small)
    call = getattr(jaxtree, fn)
    rejected(
        lambda: call(model, **kwargs),
        fn,
        r"\bmodel\b"
        if argument == "model"
        else ("hinge|set A|body|small" if argument == "small" else rf"\b{argument}\b"),
    )


HYBRID_BAD = {
    "n_modes": [0, -1, 1.5, "2", True],
    "damping": [-0.1, [0.1, 0.2, 0.3], [[0.1]], "x", math.nan],
    "form": ["modal", 3],
    "precompute": ["yes", 1],
    "attitude": ["rodrigues", 3],
    "rtol": [-1e-9, 2.0, "x", math.nan],
}


@fuzz(100)
@given(st.sampled_from(sorted(HYBRID_BAD)), st.data())
def test_bad_hybrid_options_are_named_before_tracing(small, argument, data):
    value = data.draw(st.sampled_from(HYBRID_BAD[argument]))
    rejected(lambda: jaxtree.hybrid_model(small, (1, 2), **{argument: value}), "hybrid_model", rf"\b{argument}\b")


MODES_BAD = {
    "I": [np.ones((2, 3)), "I", np.full((2, 2), np.nan), np.ones(2), np.zeros((0, 0))],
    "J": [np.ones((3, 3)), None, [[1, "a"], [0, 1]]],
    "K": [np.ones((2, 2, 1)), np.full((2, 2), np.inf)],
    "damping": [-0.1, [0.1, 0.2, 0.3], "x", math.nan, [[0.1, 0.1]]],
    "kind": ["complex", 3],
    "labels": ["ab", ["a"], 3],
    "rtol": [-1.0, "x", math.inf],
}


@fuzz(120)
@given(st.sampled_from(sorted(MODES_BAD)), st.data())
def test_bad_modes_arguments_are_named_before_tracing(argument, data):
    value = data.draw(st.sampled_from(MODES_BAD[argument]))
    args = {"I": np.diag([2.0, 3.0]), "J": np.zeros((2, 2)), "K": np.diag([4.0, 9.0])}
    kwargs = {}
    if argument in args:
        args[argument] = value
    else:
        kwargs[argument] = value
    fields = {"I": "I", "J": "J|I, J, K", "K": "K|I, J, K", "labels": "label"}.get(argument, argument)
    rejected(lambda: jaxtree.modes(args["I"], args["J"], args["K"], **kwargs), "modes", fields)
