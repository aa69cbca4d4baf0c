"""The 3D animation pages (jaxtree.viewer): the geometry they embed against closed forms, and
the pages themselves in a real browser (headless Chromium driven by Playwright)."""

import base64
import json
import os
import pathlib
import re
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jaxtree
from jaxtree._src.io import viewer

CHROMIUM = "/usr/bin/chromium"
# the page carries positions and unit quaternions as float32 (eps 6e-8) of numbers up to ~10
FLOAT32 = 1e-6


# ----------------------------------------------------------------------------- helpers
def embedded(page_html):
    """The data block of a page, with positions (T, n+1, 3) and rotations (T, n+1, 3, 3)
    decoded from the base64 float32 arrays (quaternion to matrix written out here)."""
    m = re.search(r'<script type="application/json" class="jt-data">(.*?)</script>', page_html, re.S)
    data = json.loads(m.group(1))
    T, nb = len(data["times"]), len(data["bodies"])
    f32 = lambda s: np.frombuffer(base64.b64decode(s), dtype="<f4").astype(float)
    pos = f32(data["positions"]).reshape(T, nb, 3)
    w, x, y, z = np.moveaxis(f32(data["quaternions"]).reshape(T, nb, 4), -1, 0)
    rot = np.stack(
        [
            np.stack([w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z], -1),
        ],
        -2,
    )
    return data, pos, rot


def two_body(m0=40.0, m1=3.0, axis=(0.3, -0.4, 0.866), p=(1.2, 0.1, -0.3), q=(-0.5, 0.2, 0.05)):
    axis = np.asarray(axis) / np.linalg.norm(axis)
    bodies = [
        jaxtree.Body("hub", m0, np.diag([20.0, 25.0, 30.0])),
        jaxtree.Body("arm", m1, np.diag([0.1, 0.6, 0.65]), parent=0, axis=axis, hinge_on_parent=p, hinge_on_body=q),
    ]
    return jaxtree.build_model(bodies, name="two_body"), axis, np.asarray(p), np.asarray(q)


def two_body_closed_form(m0, m1, axis, p, q, C, gamma):
    """Mass centers about the system mass center and body-to-inertial rotations, inertial
    components: b_1's mass center is d = p - R(g, gamma) q from b_0's (b_0 components), so
    rho_0 = -m1 d / M and rho_1 = m0 d / M; components go to {i} with C^T."""
    R1 = Rotation.from_rotvec(gamma[:, None] * axis).as_matrix()  # C^{01}: a turn gamma about g
    d = p - R1 @ q
    M = m0 + m1
    rho = np.stack([-m1 / M * d, m0 / M * d], 1)
    pos = np.einsum("tji,tkj->tki", C, rho)
    rot = np.stack([np.swapaxes(C, 1, 2), np.swapaxes(C, 1, 2) @ R1], 1)
    return pos, rot


# ----------------------------------------------------------------------------- geometry
def test_inertia_box_reproduces_the_principal_moments():
    """A uniform box of mass m and half-widths a, b, c has I1 = m/3 (b^2 + c^2) etc. about its
    edges: the box of random inertias (random principal moments and axes) gives them back."""
    rng = np.random.default_rng(5)
    for _ in range(20):
        m = rng.uniform(0.1, 100)
        abc = rng.uniform(0.05, 3.0, 3)
        moments = m / 3 * np.array([abc[1] ** 2 + abc[2] ** 2, abc[0] ** 2 + abc[2] ** 2, abc[0] ** 2 + abc[1] ** 2])
        V = Rotation.random(random_state=rng).as_matrix()
        J = V @ np.diag(moments) @ V.T
        half, axes = viewer.inertia_box(m, J)
        np.testing.assert_allclose(axes.T @ axes, np.eye(3), atol=1e-12)
        assert np.linalg.det(axes) == pytest.approx(1.0)
        a, b, c = half
        box = m / 3 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
        np.testing.assert_allclose(axes @ box @ axes.T, J, rtol=1e-10, atol=1e-12 * m)
        np.testing.assert_allclose(np.sort(half), np.sort(abc), rtol=1e-8)


def test_thin_and_massless_bodies_get_a_visible_box():
    """A flat plate (I3 = I1 + I2: zero thickness) is drawn with the minimum thickness, a
    massless body as a small marker; the other half-widths are the plate's."""
    plate = np.diag([0.5 / 3 * 0.04, 0.5 / 3 * 1.0, 0.5 / 3 * 1.04])  # m = 0.5, a = 1, b = 0.2, c = 0
    bodies = [
        jaxtree.Body("hub", 10.0, np.diag([1.0, 1.2, 1.4])),
        jaxtree.Body(
            "plate", 0.5, plate, parent=0, axis=[0, 1, 0], hinge_on_parent=[0.8, 0, 0], hinge_on_body=[-1.0, 0, 0]
        ),
        jaxtree.Body(
            "frame",
            0.0,
            np.zeros((3, 3)),
            parent=1,
            axis=[1, 0, 0],
            hinge_on_parent=[1.0, 0, 0],
            hinge_on_body=[0, 0, 0],
        ),
    ]
    model = jaxtree.build_model(bodies)
    half, _ = viewer.inertia_box(0.5, plate)
    np.testing.assert_allclose(np.sort(half), [0.0, 0.2, 1.0], atol=1e-7)
    data, _, _ = embedded(viewer.animation_html(model, [0.0], np.eye(3)[None], np.zeros((1, 2))))
    plate_box, frame_box = data["bodies"][1], data["bodies"][2]
    assert sorted(plate_box["half"])[1:] == pytest.approx([0.2, 1.0])
    assert sorted(plate_box["half"])[0] == pytest.approx(viewer.THIN * 1.0)
    assert frame_box["marker"] and not plate_box["marker"]
    assert frame_box["half"][0] == frame_box["half"][1] == frame_box["half"][2] > 0


def test_embedded_poses_match_the_two_body_closed_form():
    """The positions and rotations a page carries equal the closed form of a two-body tree at
    random angles and attitudes, and the hinge point the page rebuilds from b_1's pose (its
    hinge_on_body) is the one b_0 carries (its hinge_on_parent)."""
    model, axis, p, q = two_body()
    rng = np.random.default_rng(1)
    T = 7
    ts = np.linspace(0.0, 3.0, T)
    gamma = rng.uniform(-np.pi, np.pi, (T, 1))
    C = Rotation.random(T, random_state=rng).as_matrix()
    data, pos, rot = embedded(viewer.animation_html(model, ts, C, gamma, title="two <bodies> & a hinge"))
    want_pos, want_rot = two_body_closed_form(40.0, 3.0, axis, p, q, C, gamma[:, 0])
    np.testing.assert_allclose(pos, want_pos, atol=FLOAT32)
    np.testing.assert_allclose(rot, want_rot, atol=FLOAT32)
    np.testing.assert_allclose(data["times"], ts)
    hinge = data["hinges"][0]
    from_b1 = pos[:, 1] + np.einsum("tij,j->ti", rot[:, 1], hinge["point"])
    from_b0 = pos[:, 0] + np.einsum("tij,j->ti", rot[:, 0], p)
    np.testing.assert_allclose(from_b1, from_b0, atol=FLOAT32)
    np.testing.assert_allclose(
        np.einsum("tij,j->ti", rot[:, 1], hinge["axis"]), np.einsum("tij,j->ti", rot[:, 0], axis), atol=FLOAT32
    )
    assert data["title"] == "two <bodies> & a hinge"


def test_long_results_are_decimated_and_bad_input_is_named():
    model, *_ = two_body()
    T = 5001
    ts = np.linspace(0.0, 50.0, T)
    gamma = np.sin(ts)[:, None]
    C = np.broadcast_to(np.eye(3), (T, 3, 3))
    data, pos, _ = embedded(viewer.animation_html(model, ts, C, gamma))
    assert len(data["times"]) == viewer.MAX_FRAMES
    assert data["times"][0] == 0.0 and data["times"][-1] == 50.0
    kept = np.searchsorted(ts, data["times"])
    np.testing.assert_array_equal(ts[kept], data["times"])  # saved frames, evenly spread
    assert set(np.diff(kept)) == {2, 3}
    np.testing.assert_allclose(pos[:, 1], viewer.poses(model, C[kept], gamma[kept])[0][:, 1], atol=FLOAT32)
    # rows after an early stop (inf times) are dropped
    ts2 = np.concatenate([ts[:10], [np.inf] * 3])
    data, _, _ = embedded(viewer.animation_html(model, ts2, C[:13], gamma[:13]))
    assert len(data["times"]) == 10
    with pytest.raises(ValueError, match="gamma has shape"):
        viewer.animation_html(model, ts, C, np.zeros((T, 2)))
    with pytest.raises(ValueError, match="dcm has shape"):
        viewer.animation_html(model, ts, C[:-1], gamma)
    bad = gamma.copy()
    bad[7] = np.nan
    with pytest.raises(ValueError, match="gamma is not finite at t = 0.07"):
        viewer.animation_html(model, ts, C, bad)
    with pytest.raises(ValueError, match="shape has shape"):
        viewer.mode_html(model, np.ones(2), 1.0)


def test_mode_page_oscillates_the_shape_about_the_nominal_angles(tmp_path):
    """Frame j of a mode page is the tree at gamma0 + A shape sin(2 pi j / 64) (closed form); the
    file is written in place of an older one and no temporary file is left."""
    model, axis, p, q = two_body()
    A, gamma0 = 0.3, np.array([0.2])
    path = tmp_path / "mode.html"
    path.write_text("old")
    viewer.write_mode_animation(path, model, np.array([-1.5]), 2.0, gamma=gamma0, amplitude=A)
    assert [f.name for f in tmp_path.iterdir()] == ["mode.html"]
    data, pos, rot = embedded(path.read_text())
    T = viewer.MODE_FRAMES
    period = 2 * np.pi / 2.0
    np.testing.assert_allclose(data["times"], np.arange(T) * period / T)
    assert data["period"] == pytest.approx(period)
    angle = gamma0[0] + A * -1.5 * np.sin(2 * np.pi * np.arange(T) / T)
    want_pos, want_rot = two_body_closed_form(40.0, 3.0, axis, p, q, np.broadcast_to(np.eye(3), (T, 3, 3)), angle)
    np.testing.assert_allclose(pos, want_pos, atol=FLOAT32)
    np.testing.assert_allclose(rot, want_rot, atol=FLOAT32)
    # A complex (gyroscopic) shape plays Im(shape e^{i w t}): i s gives s cos(w t).
    _, pos_c, _ = embedded(viewer.mode_html(model, np.array([-1.5j]), 2.0, gamma=gamma0, amplitude=A))
    cos_pos, _ = two_body_closed_form(
        40.0,
        3.0,
        axis,
        p,
        q,
        np.broadcast_to(np.eye(3), (T, 3, 3)),
        gamma0[0] + A * -1.5 * np.cos(2 * np.pi * np.arange(T) / T),
    )
    np.testing.assert_allclose(pos_c, cos_pos, atol=FLOAT32)
    # The default amplitude moves a mass center by 15 % of the radius (here, a long arm, before
    # the angle reaches 0.35 rad): the arm's largest excursion from the nominal pose.
    long_arm, *_ = two_body(q=(-2.0, 0.2, 0.05))
    data, pos, rot = embedded(viewer.mode_html(long_arm, np.array([1.0]), 2.0))
    swing = np.linalg.norm(pos[:, 1] - pos[0, 1], axis=-1).max()
    size = np.linalg.norm(pos[0], axis=-1).max()
    assert swing == pytest.approx(0.15 * size, rel=0.01)
    turn = Rotation.from_matrix(np.swapaxes(rot[:, 0], 1, 2) @ rot[:, 1]).magnitude()
    assert 0.1 < turn.max() < 0.35


def test_expand_shape_spreads_a_linearization_over_the_hinges():
    model = jaxtree.load_scene("wings")

    class Lin:
        hinges = (0, 0, 0, 2, 6)

    shape, rotation = viewer.expand_shape(model, Lin, np.array([0.1, 0.2, 0.3, 1.0, -2.0]))
    np.testing.assert_array_equal(shape, [0, 1.0, 0, 0, 0, -2.0, 0, 0])
    np.testing.assert_array_equal(rotation, [0.1, 0.2, 0.3])
    shape, rotation = viewer.expand_shape(model, (3,), np.array([1j]))
    assert rotation is None and shape[2] == 1j and shape.dtype.kind == "c"


# ----------------------------------------------------------------------------- browser
def _require_browser():
    """Playwright and Debian's chromium; .ci/run installs chromium, so CI fails without them."""
    missing = None
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        missing = "playwright (the test extra)"
    if missing is None and not (os.path.exists(CHROMIUM) or shutil.which("chromium")):
        missing = f"{CHROMIUM} (Debian's chromium package; .ci/run installs it)"
    if missing:
        if os.environ.get("CI"):
            pytest.fail(f"browser test needs {missing}")
        pytest.skip(f"browser test needs {missing}")


@pytest.fixture(scope="module")
def browser():
    _require_browser()
    from playwright.sync_api import sync_playwright

    exe = CHROMIUM if os.path.exists(CHROMIUM) else shutil.which("chromium")
    args = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--disable-default-apps",
        "--disable-extensions",
    ]
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=exe, args=args)
        yield b
        b.close()


@pytest.fixture(scope="module")
def wings_pages(tmp_path_factory):
    """A short simulated result of the wings scene (a larger initial deflection and spin than
    the scene's, so that the motion shows) and the page of its first hinge mode."""
    model = jaxtree.load_scene("wings")
    y0 = model.initial._replace(gamma=6 * model.initial.gamma, omega0=10 * model.initial.omega0)
    sol = jaxtree.simulate(model, 1.0, saveat=51, y0=y0)
    lin = jaxtree.linearize(model, ("wingp_1", "wingm_1"))
    md = jaxtree.modes(lin)
    shape, rotation = viewer.expand_shape(model, lin, md.shapes[:, 0])
    folder = tmp_path_factory.mktemp("pages")
    viewer.write_animation(folder / "wings.html", model, sol.ts, sol.dcm, sol.gamma)
    viewer.write_mode_animation(folder / "wings_mode.html", model, shape, md.frequencies[0])
    return model, sol, folder


def _canvas_shot(page, path):
    import matplotlib.image

    page.locator("canvas.jt-canvas").screenshot(path=str(path))
    return matplotlib.image.imread(str(path))[..., :3]


def _open(browser, path):
    """Load a page; every console message, page error and request is recorded."""
    page = browser.new_page(viewport={"width": 900, "height": 640})
    log = {"errors": [], "requests": [], "failed": []}
    page.on("console", lambda m: m.type == "error" and log["errors"].append(m.text))
    page.on("pageerror", lambda e: log["errors"].append(str(e)))
    page.on("request", lambda r: log["requests"].append(r.url))
    page.on("requestfailed", lambda r: log["failed"].append(r.url))
    url = pathlib.Path(path).resolve().as_uri()
    page.goto(url)
    page.wait_for_function("document.querySelector('.jaxtree-viewer').jaxtreeViewer !== undefined")
    return page, log, url


def _played_frames_differ(page, log, url, tmp_path, name):
    before = _canvas_shot(page, tmp_path / f"{name}_0.png")
    background = np.all(before > 0.97, axis=-1)
    assert (~background).mean() > 0.02, "the canvas is (nearly) blank"
    page.click("button.jt-play")
    page.wait_for_function("document.querySelector('.jaxtree-viewer').jaxtreeViewer.frame() >= 8", timeout=10_000)
    page.evaluate("document.querySelector('.jaxtree-viewer').jaxtreeViewer.play(false)")  # hold the frame
    assert page.evaluate("document.querySelector('.jaxtree-viewer').jaxtreeViewer.frame()") >= 8
    after = _canvas_shot(page, tmp_path / f"{name}_1.png")
    changed = np.any(np.abs(after - before) > 0.05, axis=-1).mean()
    assert changed > 1e-3, f"only {changed:.2%} of the pixels changed after playing"
    assert log["errors"] == [], log["errors"]
    assert log["requests"] == [url] and log["failed"] == [], log
    return before, after


def test_result_page_plays_in_a_browser(browser, wings_pages, tmp_path):
    """The result page loads without console errors or any request but its own file, draws
    the vehicle, and shows a different picture after playing; its hinge points (rebuilt in
    the page from each body's pose) are jaxtree's configuration().hinge in inertial axes."""
    model, sol, folder = wings_pages
    page, log, url = _open(browser, folder / "wings.html")
    try:
        f = 30
        js = page.evaluate(
            f"(() => {{ const v = document.querySelector('.jaxtree-viewer').jaxtreeViewer;"
            f" return [...Array({model.n}).keys()].map(j => v.hingePoint({f}, j)); }})()"
        )
        cfg = jaxtree.configuration(model, sol.gamma[f])
        want = np.asarray(cfg.hinge) @ np.asarray(sol.dcm[f])  # C^T h, row-wise
        np.testing.assert_allclose(np.array(js), want, atol=2e-5)
        _played_frames_differ(page, log, url, tmp_path, "result")
        # The camera follows the mouse: a drag turns it, the wheel zooms.
        cam0 = page.evaluate("({...document.querySelector('.jaxtree-viewer').jaxtreeViewer.camera})")
        box = page.locator("canvas.jt-canvas").bounding_box()
        cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        page.mouse.move(cx, cy)
        page.mouse.down()
        page.mouse.move(cx + 120, cy + 40, steps=4)
        page.mouse.up()
        page.mouse.wheel(0, 300)
        cam1 = page.evaluate("({...document.querySelector('.jaxtree-viewer').jaxtreeViewer.camera})")
        assert cam1["az"] != cam0["az"] and cam1["el"] != cam0["el"] and cam1["dist"] > cam0["dist"]
        page.screenshot(path=str(tmp_path / "result_page.png"))
        assert log["errors"] == [] and log["requests"] == [url]
    finally:
        page.close()


def test_mode_page_plays_in_a_browser(browser, wings_pages, tmp_path):
    _, _, folder = wings_pages
    page, log, url = _open(browser, folder / "wings_mode.html")
    try:
        _played_frames_differ(page, log, url, tmp_path, "mode")
        page.screenshot(path=str(tmp_path / "mode_page.png"))
    finally:
        page.close()


def test_hinges_are_hidden_behind_boxes_like_the_boxes(browser, tmp_path):
    """A hinge point between the hub and the arm is hidden by the hub seen from the hub's side
    (behind it) and by the arm seen from the arm's side, and shown seen from aside; a hinge
    inside its parent's box (here at the hub's center) is not hidden by that box, only by
    another one (the arm, seen from the arm's side)."""
    bodies = [
        jaxtree.Body("hub", 40.0, np.diag([20.0, 25.0, 30.0])),
        # the hub's box reaches x = +-1.15; the hinge at x = -1.6, the arm's box from -1.84 to -3.36
        jaxtree.Body(
            "arm",
            3.0,
            np.diag([0.1, 0.6, 0.65]),
            parent=0,
            axis=(0, 0, 1),
            hinge_on_parent=(-1.6, 0, 0),
            hinge_on_body=(1.0, 0, 0),
        ),
        jaxtree.Body(
            "core",
            1.0,
            np.diag([0.01, 0.01, 0.01]),
            parent=0,
            axis=(0, 0, 1),
            hinge_on_parent=(0, 0, 0),
            hinge_on_body=(0, 0, 0),
        ),
    ]
    model = jaxtree.build_model(bodies, name="hidden_hinge")
    ts = np.linspace(0.0, 1.0, 3)
    viewer.write_animation(tmp_path / "h.html", model, ts, np.tile(np.eye(3), (3, 1, 1)), np.zeros((3, 2)))
    page, log, _ = _open(browser, tmp_path / "h.html")
    try:

        def shown(az_deg, el_deg=0.0):
            return page.evaluate(
                "(([az, el]) => { const v = document.querySelector('.jaxtree-viewer').jaxtreeViewer;"
                " v.camera.az = az * Math.PI / 180; v.camera.el = el * Math.PI / 180; v.draw();"
                " return [v.hingeShown(0), v.hingeShown(1)]; })",
                [az_deg, el_deg],
            )

        assert shown(0.0) == [False, True]  # from +x: behind the hub
        assert shown(180.0) == [False, False]  # from -x: both behind the arm
        assert shown(90.0) == [True, True] and shown(-90.0) == [True, True]  # from aside
        assert shown(0.0, 89.0) == [True, True]  # from above
        assert log["errors"] == [], log["errors"]
    finally:
        page.close()
