"""Scene loading (format jaxtree-scene/1), the builder API and input validation."""

import json

import numpy as np
import pytest

import jaxtree
from jaxtree import SceneError

from helpers import SHARED_SCENES


def test_bundled_scenes_are_the_shared_reference_scenes():
    bundled = set(jaxtree.list_scenes())
    assert {
        "fig4",
        "fig4_free",
        "appendix_b",
        "appendix_c",
        "chain10",
        "chain50",
        "chain200",
        "panels95",
        "flex95",
        "wings",
    } <= bundled
    if SHARED_SCENES.exists():  # in a checkout beside ../shared the copies must be identical
        shared = {p.stem for p in SHARED_SCENES.glob("*.json")}
        assert shared == bundled
        for name in shared:
            assert (SHARED_SCENES / f"{name}.json").read_text() == jaxtree.scene_path(name).read_text()


@pytest.mark.parametrize("name", jaxtree.list_scenes())
def test_every_scene_loads_with_its_data(name):
    data = json.loads(jaxtree.scene_path(name).read_text())
    model = jaxtree.load_scene(jaxtree.scene_path(name))
    n = len(data["bodies"]) - 1
    assert model.n == n and model.names == tuple(b["name"] for b in data["bodies"])
    np.testing.assert_array_equal(model.mass, [b["mass"] for b in data["bodies"]])
    np.testing.assert_array_equal(model.topology.parents, [b["parent"] for b in data["bodies"][1:]])
    for k, b in enumerate(data["bodies"][1:], start=1):
        joint = b["joint"]
        if joint["kind"] == "spring_damper":
            assert k in model.sprung
            assert float(model.stiffness[k - 1]) == joint["stiffness"]
            assert float(model.damping[k - 1]) == joint["damping"]
        assert (k in model.prescribed) == (joint["kind"] == "prescribed")
    np.testing.assert_array_equal(model.initial.omega0, data["initial"]["omega0"])


def test_round_trip_through_json(tmp_path):
    model = jaxtree.load_scene("fig4")
    path = tmp_path / "copy.json"
    jaxtree.save_scene(model, path)
    again = jaxtree.load_scene(path)
    assert again.topology == model.topology and again.prescribed == model.prescribed
    for field in ("mass", "inertia", "axis", "hinge_on_parent", "hinge_on_body", "stiffness", "damping"):
        np.testing.assert_array_equal(getattr(again, field), getattr(model, field))
    assert not list(tmp_path.glob(".*.tmp"))  # the atomic write leaves no temporary file


def test_builder_matches_json():
    seg = np.diag([0.2, 0.8, 1.0])
    model = jaxtree.build_model(
        [
            jaxtree.Body("hub", 100.0, np.diag([30.0, 40.0, 50.0])),
            jaxtree.Body(
                "boom",
                2.0,
                seg,
                parent="hub",
                axis=[0, 2, 0],
                hinge_on_parent=[0.6, 0, 0],
                hinge_on_body=[-0.25, 0, 0],
                joint=jaxtree.SpringDamper(400.0, 1.0),
            ),
            jaxtree.Body(
                "tip",
                2.0,
                seg,
                parent=1,
                axis=[0, 0, 1],
                hinge_on_parent=[0.25, 0, 0],
                hinge_on_body=[-0.25, 0, 0],
                joint=jaxtree.PrescribedSine(0.1, 2.0),
            ),
        ],
        {"gamma": [0.1, 0.0]},
    )
    assert model.topology.parents == (0, 1)
    np.testing.assert_array_equal(model.axis[0], [0, 1, 0])  # axes are normalised
    assert model.sprung == (1,) and model.prescribed == (2,)
    np.testing.assert_allclose(model.prescription(1.0), 0.1 * np.sin(2.0))


def _fig4():
    return json.loads(jaxtree.scene_path("fig4").read_text())


def _expect(mutate, *fragments):
    data = _fig4()
    mutate(data)
    with pytest.raises(SceneError) as err:
        jaxtree.scene_from_dict(data)
    for f in fragments:
        assert f in str(err.value), (f, str(err.value))


def _set(k, field, value):
    def mutate(d):
        d["bodies"][k][field] = value

    return mutate


def _delete(k, field):
    def mutate(d):
        del d["bodies"][k][field]

    return mutate


CASES = {
    "parent_missing": (_delete(3, "parent"), "body 3 ('gimbal_inner')", "'parent'"),
    "parent_not_less": (_set(3, "parent", 3), "body 3 ('gimbal_inner')", "'parent'", "Def. 4"),
    "parent_later_body": (_set(2, "parent", 7), "body 2 ('gimbal_outer')", "'parent'"),
    "parent_unknown_name": (_set(2, "parent", "nowhere"), "body 2", "'parent'"),
    "axis_zero": (_set(5, "axis", [0, 0, 0]), "body 5 ('panel_root')", "'axis'", "nonzero"),
    "axis_length": (_set(5, "axis", [0, 1]), "body 5 ('panel_root')", "'axis'", "length 3"),
    "axis_nan": (_set(5, "axis", [0, float("nan"), 1]), "body 5", "'axis'", "finite"),
    "negative_mass": (_set(4, "mass", -1.0), "body 4 ('rotor')", "'mass'", ">= 0"),
    "infinite_mass": (_set(4, "mass", float("inf")), "body 4 ('rotor')", "'mass'", "finite"),
    "inertia_asymmetric": (
        _set(1, "inertia", [[4, 1, 0], [0, 4, 0], [0, 0, 2]]),
        "body 1 ('platform')",
        "'inertia'",
        "symmetric",
    ),
    "inertia_indefinite": (
        _set(1, "inertia", [[4, 0, 0], [0, -1, 0], [0, 0, 2]]),
        "body 1",
        "'inertia'",
        "positive semidefinite",
    ),
    "inertia_triangle": (
        _set(1, "inertia", [[1, 0, 0], [0, 1, 0], [0, 0, 5]]),
        "body 1",
        "'inertia'",
        "triangle inequality",
    ),
    "inertia_shape": (_set(1, "inertia", [[1, 0], [0, 1]]), "body 1", "'inertia'", "3x3"),
    "massless_with_inertia": (
        _set(2, "inertia", [[1, 0, 0], [0, 1, 0], [0, 0, 1]]),
        "body 2 ('gimbal_outer')",
        "massless",
        "'inertia'",
    ),
    "hinge_vector_length": (_set(6, "hinge_on_parent", [0.5, 0]), "body 6 ('panel_2')", "'hinge_on_parent'"),
    "hinge_vector_missing": (_delete(6, "hinge_on_body"), "body 6 ('panel_2')", "'hinge_on_body'"),
    "unknown_joint": (_set(7, "joint", {"kind": "ball"}), "body 7 ('panel_3')", "unknown joint kind 'ball'"),
    "unknown_function": (_set(1, "joint", {"kind": "prescribed", "function": "cosine"}), "body 1", "'joint.function'"),
    "stiffness_nan": (_set(7, "joint", {"kind": "spring_damper", "stiffness": None}), "body 7", "'joint.stiffness'"),
    "duplicate_name": (_set(7, "name", "panel_2"), "body 7", "'name'", "duplicates body 6"),
    "gamma_length": (lambda d: d["initial"].__setitem__("gamma", [0.0] * 9), "initial", "'gamma'", "length 10"),
    "dcm_not_rotation": (
        lambda d: d["initial"].__setitem__("attitude_dcm", [[1, 0, 0], [0, 1, 0], [0, 0, -1]]),
        "initial",
        "'attitude_dcm'",
    ),
    "wrong_format": (lambda d: d.__setitem__("format", "other/2"), "'format'"),
    "reference_with_parent": (_set(0, "parent", 0), "body 0 ('bus')", "'parent'"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_invalid_input_names_body_and_field(case):
    mutate, *fragments = CASES[case]
    _expect(mutate, *fragments)


def test_spring_on_massless_branch_is_rejected():
    bodies = [
        jaxtree.Body("base", 10.0, np.eye(3)),
        jaxtree.Body("vane", 0.0, np.zeros((3, 3)), 0, [0, 0, 1], [1, 0, 0], [0, 0, 0], jaxtree.SpringDamper(5.0)),
    ]
    with pytest.raises(SceneError, match="body 1 .*massless"):
        jaxtree.build_model(bodies)


def _batch(model, runs, **leaves):
    """A batch of `runs` copies of `model` with the named leaves replaced (numpy, batched)."""
    import equinox as eqx
    import jax.numpy as jnp

    names = tuple(leaves)
    tiled = {k: np.tile(np.asarray(getattr(model, k)), (runs,) + (1,) * getattr(model, k).ndim) for k in names}
    for k, fn in leaves.items():
        fn(tiled[k])
    return eqx.tree_at(
        lambda m: tuple(getattr(m, k) for k in names), model, tuple(jnp.asarray(tiled[k]) for k in names)
    )


def test_validate_model_checks_a_batch_of_dispersed_models_and_names_the_run():
    model = jaxtree.load_scene("fig4")
    good = _batch(model, 6, mass=lambda m: m.__setitem__((slice(None), 0), m[:, 0] * np.linspace(0.9, 1.1, 6)))
    assert jaxtree.validate_model(good) is good
    assert jaxtree.validate_model(model) is model
    assert jaxtree.validate_model(model.astype(np.float32)) is not None  # float32 rounding is no error

    def flat_bus(J):  # run 4: principal moments 800, 900, 2000 (no mass distribution has them)
        J[4, 0] = np.diag([800.0, 900.0, 2000.0])

    with pytest.raises(SceneError, match=r"run \(4,\): body 0 \('bus'\): field 'inertia' violates the triangle"):
        jaxtree.validate_model(_batch(model, 6, inertia=flat_bus))
    with pytest.raises(
        SceneError, match=r"run \(2,\): body 3 \('gimbal_inner'\): fields 'mass' / 'inertia' must stay zero"
    ):
        jaxtree.validate_model(_batch(model, 6, mass=lambda m: m.__setitem__((2, 3), 1.0)))
    with pytest.raises(SceneError, match=r"run \(1,\): body 5 \('panel_root'\): field 'axis' must be a unit vector"):
        jaxtree.validate_model(_batch(model, 3, axis=lambda a: a.__setitem__((1, 4), a[1, 4] * 1.01)))
    with pytest.raises(SceneError, match=r"body 7 \('panel_3'\): field 'joint.stiffness' must be finite"):
        jaxtree.validate_model(_batch(model, 2, stiffness=lambda k: k.__setitem__((0, 6), np.nan)))
    import equinox as eqx

    with pytest.raises(SceneError, match=r"^body 0 \('bus'\): field 'mass' must be >= 0"):
        jaxtree.validate_model(eqx.tree_at(lambda m: m.mass, model, model.mass.at[0].set(-1.0)))


def test_validate_model_refuses_traced_leaves():
    import jax

    model = jaxtree.load_scene("chain10")
    with pytest.raises(TypeError, match="concrete arrays"):
        jax.jit(lambda m: jaxtree.validate_model(m).mass)(model)
