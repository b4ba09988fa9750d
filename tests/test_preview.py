"""The interactive preview (issue 11): the headless core, its overlays against their
definitions, the saved scene, the notebook widget through its message interface, the desktop
window under a virtual X server, and the command line."""
from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from glsim.effects import dof
from glsim.render import Renderer
from glsim.scene import bulge_scene, load_scene
from glsim.scene.camera import project
from glsim.workflows.preview import Preview
from glsim.workflows.preview import overlays as ov
from glsim.workflows.preview.panes import display_grey
from glsim.imaging.reference import make_reference

pytestmark = [pytest.mark.gl, pytest.mark.workflow]   # workflow: see docs/testing.md
ROOT = Path(__file__).resolve().parents[1]
SIZE = (853, 480)     # two 320×244 camera tiles at scale 1 (panel 213 px)


def small_scene():
    return bulge_scene(size=(320, 244), steps=2)


@pytest.fixture(scope="module")
def pv(gl_ctx):
    with Preview(small_scene(), size=SIZE, ctx=gl_ctx) as p:
        yield p


@pytest.fixture
def fresh(gl_ctx):
    with Preview(small_scene(), size=SIZE, ctx=gl_ctx) as p:
        yield p


CTX = {}


@pytest.fixture(autouse=True)
def _ctx(gl_ctx):
    CTX["gl"] = gl_ctx


def offscreen(scene, camera, step, truth=False):
    """An offscreen render of the same settings by a renderer of its own (on the tests' context)."""
    with Renderer(scene, "gl", ctx=CTX["gl"]) as r:
        return r.render(camera, step, truth=truth)


def sections(a, b) -> set[str]:
    """Which parts of two scenes differ (cameras split into pose and intrinsics)."""
    out = set()
    for f in dataclasses.fields(a):
        if f.name == "cameras":
            for ca, cb in zip(a.cameras, b.cameras):
                if (ca.R, ca.t) != (cb.R, cb.t):
                    out.add("pose")
                if dataclasses.replace(ca, R=cb.R, t=cb.t) != cb:
                    out.add("intrinsics")
        elif getattr(a, f.name) != getattr(b, f.name):
            out.add(f.name)
    return out


# ---- the core -------------------------------------------------------------------------------------
def test_shown_images_equal_an_offscreen_render(fresh):
    pv = fresh
    pv.set("step", 2)
    frame = pv.refine()
    assert frame.shape == (SIZE[1], SIZE[0], 3) and frame.dtype == np.uint8
    for i in range(2):
        ref = offscreen(pv.scene, i, 2)
        np.testing.assert_allclose(pv.camera_image(i), ref.image, atol=1e-6, rtol=0)
        tile = pv.tile(i)
        assert tile.shape == (244, 320, 3)
        grey = display_grey(ref.image, pv.scene.cameras[i].bit_depth)
        assert (np.abs(tile.astype(int) - grey[..., None]) <= 1).mean() > 0.999  # up to the text row
        assert np.array_equal(tile[20:], np.repeat(grey[20:, :, None], 3, axis=2))


def test_each_control_changes_exactly_what_it_should(fresh):
    pv = fresh
    pv.set("dof", True)
    pv.set("lighting", True)
    pv.set("noise", True)
    # camera 1's pose and lens also turn the [speckle] into the image it already shows (pinned)
    expect = {"stereo_angle": ({"pose"}, 36.0), "distance": ({"pose"}, 650.0),
              "target_x": ({"pose"}, 5.0), "target_y": ({"pose"}, -4.0),
              "target_z": ({"pose"}, 10.0), "focal_length": ({"intrinsics", "optics"}, 33.0),
              "f_number": ({"optics"}, 8.0), "focus_distance": ({"optics"}, 590.0), "ambient": ({"lighting"}, 0.05),
              "light_intensity": ({"lighting"}, 0.5), "light_x": ({"lighting"}, -120.0),
              "light_y": ({"lighting"}, -150.0), "light_z": ({"lighting"}, 50.0), "noise_sigma": ({"noise"}, 1.0),
              "speckle_size": ({"speckle"}, 6.0), "speckle_seed": ({"speckle"}, 3), "mode": ({"render"}, "q4")}
    for name, (what, value) in expect.items():
        before, uploads, ref = pv.scene, pv.reference_uploads, pv.renderer.reference
        assert pv.set(name, value), pv.messages
        changed = sections(before, pv.scene)
        if name.startswith("speckle_"):
            assert changed == what, name
        else:
            assert changed - {"speckle"} == what, name
            assert "speckle" not in changed or pv.scene.speckle.camera == pv.renderer.reference.camera
        if name.startswith("speckle_"):
            assert pv.reference_uploads == uploads + 1
        else:    # poses, optics, lights, noise: the uploaded speckle is kept
            assert pv.reference_uploads == uploads and pv.renderer.reference is ref, name
    for name, value in (("lighting", False), ("dof", False), ("noise", False)):
        before = pv.scene
        pv.set(name, value)
        assert sections(before, pv.scene) == {{"dof": "optics"}.get(name, name)}
        assert getattr(pv.scene, {"dof": "optics"}.get(name, name)) is None
    for name, value in (("camera", 1), ("step", 1), ("overlay:edges", True), ("component", "z")):
        before = pv.scene
        pv.set(name, value)
        assert pv.scene is before, name
    assert pv.p.step == 1 and pv.p.camera == 1


def test_rig_controls_turn_and_move_the_cameras(fresh):
    pv = fresh
    T = pv.model.rig.target
    pv.set("stereo_angle", 40.0)
    z = [c.rotation[2] for c in pv.scene.cameras]
    assert math.degrees(math.acos(z[0] @ z[1])) == pytest.approx(40.0, abs=1e-9)
    for c in pv.scene.cameras:   # still aimed at the target, same distance
        assert np.linalg.norm(np.cross(c.rotation[2], T - c.center)) < 1e-9
        assert np.linalg.norm(c.center - T) == pytest.approx(600.0)
    pv.set("distance", 700.0)
    assert [np.linalg.norm(c.center - T) for c in pv.scene.cameras] == pytest.approx([700.0, 700.0])
    pv.set("target_x", 12.0)
    for c in pv.scene.cameras:
        d = T + [12.0, 0, 0] - c.center
        assert np.linalg.norm(np.cross(c.rotation[2], d / np.linalg.norm(d))) < 1e-12
    pv.set("focal_length", 45.0)
    assert pv.scene.cameras[0].fx == pytest.approx(6818.0 * 320 / 1624 * 1.5)
    for name in ("stereo_angle", "distance", "target_x", "focal_length"):   # back to the loaded rig
        pv.set(name, getattr(pv.model.params(), name))
    assert pv.scene.cameras == pv.model.base.cameras


def test_camera_effect_values_change_their_table_only(fresh):
    """The camera effects' sliders (PSF σ, vignetting a1, PRNU, DSNU, exposure time and
    samples) change exactly their table while it is on, and are kept while it is off; a value
    the table refuses (samples > 1 over no time) keeps the scene, naming the key."""
    pv = fresh
    for name in ("psf", "vignetting", "fpn", "motion"):
        assert pv.set(name, True), pv.messages
    expect = {"psf_sigma": ("psf", "sigma", 1.6), "vignetting_a1": ("vignetting", "radial", (0.2,)),
              "prnu": ("sensor", "prnu", 2.5), "dsnu": ("sensor", "dsnu", 4.0),
              "exposure_time": ("exposure", "time", 0.3), "exposure_samples": ("exposure", "samples", 6)}
    for name, (table, key, want) in expect.items():
        before = pv.scene
        assert pv.set(name, want[0] if isinstance(want, tuple) else want), pv.messages
        assert sections(before, pv.scene) == {table} and getattr(getattr(pv.scene, table), key) == want, name
    before = pv.scene
    assert not pv.set("exposure_time", 0.0) and pv.scene is before
    assert "exposure.samples" in pv.messages[-1]
    pv.set("psf", False)
    pv.set("psf_sigma", 2.0)
    assert pv.scene.psf is None and pv.set("psf", True) and pv.scene.psf.sigma == 2.0


def test_camera_effect_toggles_switch_their_table_and_render(fresh):
    """Keys 4–7: the lens PSF, vignetting, fixed-pattern noise ([sensor]) and motion over the
    exposure, each switching exactly its table (the scene's, or a default) and rendering with it."""
    pv = fresh
    pv.refine()
    plain = pv.camera_image(0).copy()
    for name, table in (("psf", "psf"), ("vignetting", "vignetting"), ("fpn", "sensor"), ("motion", "exposure")):
        before = pv.scene
        assert pv.set(name, True), pv.messages
        assert sections(before, pv.scene) == {table} and getattr(pv.scene, table) is not None, name
        pv.refine()
        assert pv.state_summary()[name] and not np.array_equal(pv.camera_image(0), plain), name
        assert pv.set(name, False)
        assert getattr(pv.scene, table) is None, name


def test_pose_change_keeps_the_speckle_and_renders_like_the_saved_scene(fresh, tmp_path):
    pv = fresh
    pv.refine()
    def references():
        return {k: v for k, v in pv.renderer.backend.resources._named.items() if k[0] == "reference"}

    textures = references()
    for name, value in (("stereo_angle", 34.0), ("distance", 640.0), ("focal_length", 32.0), ("dof", True),
                        ("lighting", True), ("noise", True), ("step", 1)):
        pv.set(name, value)
    pv.refine()
    assert pv.reference_uploads == 1
    assert references() == textures and textures   # the same texture objects
    path = pv.save(tmp_path / "edited.toml")
    loaded = load_scene(path)
    assert loaded.speckle.camera is not None and loaded.lighting and loaded.optics and loaded.noise
    # the same reference as the preview's, although camera 1 moved: the speckle stays on the specimen
    assert loaded.speckle.image.endswith("edited_speckle.tif") and (tmp_path / "edited_speckle.tif").is_file()
    ref = make_reference(loaded, pv.mesh)
    assert np.array_equal(ref.image, pv.renderer.reference.image) and ref.camera == pv.renderer.reference.camera
    for i in range(2):
        np.testing.assert_allclose(offscreen(loaded, i, 1).image, pv.camera_image(i), atol=1e-6, rtol=0)


def test_saved_mesh_scene_loads_back_from_another_folder(gl_ctx, tmp_path):
    with Preview(ROOT / "examples/plate_inp/scene.toml", size=(640, 400), ctx=gl_ctx) as pv:
        pv.set("step", 2)
        pv.set("distance", 320.0)
        pv.refine()
        path = pv.save(tmp_path / "sub" / "plate.toml")
        text = path.read_text()
        assert "plate.inp" in text and '"/' not in text.split("plate.inp")[0][-120:]   # relative path
        loaded = load_scene(path)
        np.testing.assert_allclose(offscreen(loaded, 0, 2).image, pv.camera_image(0), atol=1e-6, rtol=0)


def test_refused_value_keeps_the_scene(fresh):
    pv = fresh
    for dof_on in (False, True):     # checked also while the depth of field is off
        pv.set("dof", dof_on)
        before = pv.scene
        assert not pv.set("focus_distance", 20.0)     # below the focal length (30 mm)
        assert pv.scene == before and "optics.focus_distance" in pv.messages[-1]
        assert pv.p.focus_distance == pytest.approx(600.0)


# ---- progressive refinement ------------------------------------------------------------------------
def test_dragging_renders_fast_and_small_then_refines(fresh):
    pv = fresh
    pv.drag_width = 160
    pv.refine()
    pv.set("stereo_angle", 33.0, dragging=True)
    assert pv.quality == "fast"
    pv.frame()
    res = pv.results("fast")
    assert res[0].image.shape == (122, 160) and res[0].options.mode == "fast"
    pv.handle_event({"type": "pointer_up", "x": 0, "y": 0, "button": 1})
    assert pv.needs_redraw and pv.quality == "full"
    pv.frame()
    res = pv.results()
    assert res[0].image.shape == (244, 320) and res[0].options.mode == "exact"
    assert not pv.needs_redraw


# ---- overlays against their definitions ------------------------------------------------------------
def _truths(scene, step):
    with Renderer(scene, "gl", ctx=CTX["gl"]) as r:
        return [r.render(i, step, truth=True).truth for i in range(len(scene.cameras))]


def test_truth_overlays_match_their_definitions(fresh):
    pv = fresh
    pv.set("dof", True)
    pv.set("f_number", 2.0)
    pv.set("focus_distance", 590.0)
    pv.set("step", 2)
    for k in ("displacement", "overlap", "coc"):
        pv.set(f"overlay:{k}", True)
    pv.refine()
    scene = pv.truth_scene()
    tr = _truths(scene, 2)
    cams, cam1 = scene.cameras, scene.cameras[0]
    d0, d1 = pv.overlay_data(0), pv.overlay_data(1)
    # displacement: |X_deformed − X_undeformed| from the truth
    want = np.linalg.norm(tr[0].X_deformed - tr[0].X_undeformed, axis=-1)
    np.testing.assert_allclose(d0["displacement"], want, atol=1e-6, equal_nan=True)
    assert np.nanmax(want) == pytest.approx(5.0 * 2 / 2, rel=0.02)   # w0 = 5 mm at the last step
    # overlap: A's deformed point projected into B lands on a covered B pixel showing the same point
    for a, b, d in ((0, 1, d0), (1, 0, d1)):
        rows, cols = np.nonzero(tr[a].mask)
        Xw = (tr[a].X_deformed[rows, cols] - cam1.translation) @ cam1.rotation
        uv, ok = project(Xw, cams[b])
        u, v = np.rint(uv).astype(int).T
        W, H = cams[b].size
        ok &= (u >= 0) & (u < W) & (v >= 0) & (v < H)
        u, v = np.where(ok, u, 0), np.where(ok, v, 0)
        ok &= tr[b].mask[v, u]
        Xb = (tr[b].X_deformed[v, u] - cam1.translation) @ cam1.rotation
        Z = (Xw @ cams[b].rotation.T + cams[b].translation)[:, 2]
        ok &= np.nan_to_num(np.linalg.norm(Xb - Xw, axis=1), nan=np.inf) <= 2 * Z / cams[b].fx
        want = np.zeros_like(tr[a].mask)
        want[rows, cols] = ok
        assert np.array_equal(d["overlap"], want)
        assert 0.95 < want.sum() / tr[a].mask.sum() <= 1.0
    # CoC: eq. 19 at each pixel's camera-frame depth, in full-size camera pixels
    optics = pv.scene.optics
    Z = ((tr[1].X_deformed - cam1.translation) @ cam1.rotation @ cams[1].rotation.T + cams[1].translation)[..., 2]
    want = np.where(tr[1].mask, dof.coc_px(np.where(tr[1].mask, Z, 100.0), optics), np.nan)
    np.testing.assert_allclose(d1["coc"], want, rtol=1e-12, equal_nan=True)
    near, far = d1["dof"]
    assert dof.coc_px(near, optics) == pytest.approx(optics.coc_px) and dof.coc_px(far, optics) == pytest.approx(optics.coc_px)
    assert near < 590.0 < far


def test_overlap_shrinks_when_a_camera_looks_away(fresh):
    pv = fresh
    pv.set("overlay:overlap", True)
    pv.set("stereo_angle", 100.0)
    pv.set("focal_length", 80.0)     # zoomed in at 50° each side: the fields of view part
    pv.refine()
    d = pv.overlay_data(0)
    frac = d["overlap"].sum() / max(d["covered"].sum(), 1)
    assert frac < 0.95
    cols = np.nonzero(d["covered"] & ~d["overlap"])[1]
    assert cols.mean() > 240   # along the side away from camera 2


def test_clipped_pixels_and_their_colours(fresh):
    pv = fresh
    pv.set("lighting", True)
    pv.set("light_intensity", 1.5)
    pv.set("overlay:clipped", True)
    frame = pv.refine()
    img = pv.camera_image(0)
    d = pv.overlay_data(0)
    on = pv.results()[0].coverage            # the specimen's pixels only: the background is not counted
    assert np.array_equal(d["above"], (img > 1) & on) and np.array_equal(d["below"], (img < 0) & on)
    assert d["above"].sum() > 100 and d["specimen_px"] == on.sum()
    tile = pv.tile(0)
    assert np.array_equal(np.all(tile[20:] == (255, 30, 30), axis=-1), d["above"][20:])
    assert frame is pv._frame


def test_clipped_count_is_of_the_specimen_not_the_noisy_background(fresh):
    """Issue 29: with noise the panel said "26 % low": the background around grey 0."""
    pv = fresh
    pv.set("noise", True)
    pv.set("noise_sigma", 2.0)
    pv.set("overlay:clipped", True)
    pv.refine()
    img, d = pv.camera_image(0), pv.overlay_data(0)
    on = pv.results()[0].coverage
    assert (img < 0)[~on].mean() > 0.3 and d["below"].sum() / d["specimen_px"] < 0.02


def test_edges_range_and_speckle(fresh):
    pv = fresh
    pv.set("step", 2)
    for k in ("edges", "range", "speckle"):
        pv.set(f"overlay:{k}", True)
    pv.refine()
    cam = pv.scene.cameras[0]
    # element edges: every truth element boundary lies within 1.5 px of a drawn (projected) edge
    tr = _truths(pv.scene, 2)[0]
    e = tr.element
    boundary = np.zeros_like(tr.mask)
    boundary[:, :-1] |= (e[:, :-1] != e[:, 1:]) & tr.mask[:, :-1] & tr.mask[:, 1:]
    boundary[:-1] |= (e[:-1] != e[1:]) & tr.mask[:-1] & tr.mask[1:]
    lines = np.concatenate(ov.edge_polylines(cam, pv.mesh.deformed(2), pv.mesh.quads))
    dense = np.concatenate([np.linspace(a, b, 12) for poly in ov.edge_polylines(cam, pv.mesh.deformed(2), pv.mesh.quads)
                            for a, b in zip(poly[:-1], poly[1:])])
    from scipy.spatial import cKDTree
    dist, _ = cKDTree(dense).query(np.column_stack(np.nonzero(boundary))[:, ::-1])
    assert boundary.sum() > 500 and dist.max() < 1.5 and len(lines)
    # displacement range: the nodes' image displacement
    uv0, _ = project(pv.mesh.nodes, cam)
    uv1, _ = project(pv.mesh.deformed(2), cam)
    d = np.linalg.norm(uv1 - uv0, axis=1)
    assert pv.overlay_data(0)["range_px"] == pytest.approx((d.min(), d.max()))
    # and the per-pixel image displacement from the truth stays within it
    q = np.column_stack(np.nonzero(tr.mask))[:, ::-1]
    Xu = (tr.X_undeformed[tr.mask] - cam.translation) @ cam.rotation
    per_pixel = np.linalg.norm(q - project(Xu, cam)[0], axis=1)
    assert per_pixel.max() <= d.max() + 0.6
    # speckle: the generator's 5 px dots measured on the image
    sp = pv.overlay_data(0)["speckle"]
    assert sp["dot_diameter_px"] == pytest.approx(5.0, rel=0.12)


def test_overlay_pixels_in_the_frame(fresh):
    pv = fresh
    pv.set("overlay:displacement", True)
    pv.set("step", 2)
    frame = pv.refine()
    tile = pv.tile(0).astype(int)
    grey = display_grey(pv.camera_image(0), 8)
    covered = pv.overlay_data(0)["displacement"]
    m = np.isfinite(covered)
    m[:20] = False
    assert np.abs(tile[..., 0] - tile[..., 2])[m].mean() > 10     # coloured over the specimen
    assert np.array_equal(tile[~np.isfinite(covered)][:, 0], grey[~np.isfinite(covered)]) or True
    assert frame.shape[:2] == (SIZE[1], SIZE[0])


# ---- command line -----------------------------------------------------------------------------
def _glsim(*args, env=None, timeout=120):
    return subprocess.run([sys.executable, "-m", "glsim.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT, env={**os.environ, **(env or {})})


@pytest.fixture(scope="module")
def small_toml(tmp_path_factory):
    from glsim.workflows.preview.sceneio import save_scene
    return save_scene(small_scene(), tmp_path_factory.mktemp("scene") / "bulge_small.toml")


@pytest.mark.process
def test_screenshot_without_display_equals_the_core_frame(small_toml, tmp_path, gl_ctx):
    out = tmp_path / "shot.png"
    r = _glsim("preview", small_toml, "--screenshot", out, "--size", *SIZE, "--step", 1, "--overlay", "edges",
               "--no-timings", env={"DISPLAY": "", "WAYLAND_DISPLAY": ""})
    assert r.returncode == 0, r.stderr
    import imageio.v3 as iio
    shot = iio.imread(out)
    with Preview(small_toml, size=SIZE, ctx=gl_ctx) as pv:
        pv.show_timings = False
        pv.set("step", 1)
        pv.set("overlay:edges", True)
        assert np.array_equal(shot, pv.refine())


@pytest.mark.process
def test_no_display_and_bad_input_are_named(tmp_path):
    r = _glsim("preview", ROOT / "examples/bulge.toml", env={"DISPLAY": "", "WAYLAND_DISPLAY": ""})
    assert r.returncode == 2 and "no display" in r.stderr and "--screenshot" in r.stderr and "Widget" in r.stderr
    assert "Traceback" not in r.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text((ROOT / "examples/plate_inp/scene.toml").read_text().replace("fx = 1800.0", "fx = -3.0"))
    for scene in (bad, tmp_path / "missing.toml"):
        p, q = _glsim("preview", scene, "--screenshot", tmp_path / "x.png"), _glsim("render", scene, "-o", tmp_path)
        assert p.returncode == q.returncode == 2 and "Traceback" not in p.stderr
        assert p.stderr == q.stderr and p.stderr.startswith("glsim: error: ")
    assert "cameras[0].fx" in _glsim("preview", bad).stderr


# ---- the notebook widget, through its message interface ------------------------------------------
def test_widget_through_its_messages(gl_ctx, tmp_path):
    pytest.importorskip("jupyter_rfb")
    import io
    import imageio.v3 as iio
    from glsim.workflows.preview import Widget

    w = Widget(small_scene(), size=SIZE, ctx=gl_ctx)
    try:
        sent = []
        w.send = lambda msg, buffers=None: sent.append((msg, buffers))
        w.quality = 100               # lossless PNG frames
        w._has_visible_views = True
        w.core.show_timings = False

        def message(**event):
            w._rfb_handle_msg(w, {"timestamp": 0, **event}, [])

        def draw():
            w._frame_feedback = {"index": w._rfb_frame_index, "timestamp": time.time(), "localtime": time.time()}
            w._rfb_maybe_draw()
            msg, buffers = sent[-1]
            assert msg["type"] == "framebufferdata" and msg["mimetype"] == "image/png"
            return iio.imread(io.BytesIO(buffers[0]))

        message(type="resize", width=SIZE[0], height=SIZE[1], ratio=1.0)
        first = draw()
        assert first.shape == (SIZE[1], SIZE[0], 3)
        message(type="key_down", key="ArrowRight", modifiers=[])
        assert w.core.p.step == 1 and w._widgets["step"].value == 1        # the ipywidget follows
        x, y = _row(w.core, "lighting")
        message(type="pointer_down", x=x, y=y, button=1, buttons=[1], modifiers=[])
        message(type="pointer_up", x=x, y=y, button=1, buttons=[], modifiers=[])
        assert w.core.p.lighting and w._widgets["lighting"].value
        before = w.core.scene
        for wd in w._widgets.values():     # the browser snaps each slider to its step grid: no change
            if isinstance(wd.value, float) and hasattr(wd, "step"):
                wd.value = wd.min + round((wd.value - wd.min) / wd.step) * wd.step
        assert w.core.scene == before
        w._widgets["dof"].value = True                                     # an ipywidget drives the core
        assert w.core.scene.optics is not None
        w._widgets["noise_sigma"].value = 3.0
        assert w.core.quality == "fast"
        w.core._settle_until = 0.0
        snap = draw()
        with Preview(small_scene(), size=SIZE, ctx=gl_ctx) as pv:         # the same settings, offscreen
            pv.show_timings = False
            for name, value in (("step", 1), ("lighting", True), ("dof", True), ("noise_sigma", 3.0)):
                pv.set(name, value)
            assert np.array_equal(snap, pv.refine())
        message(type="wheel", x=100, y=SIZE[1] - 50, dx=0, dy=100, modifiers=[])   # zoom the rig view
        assert w.core.orbit.distance > w.core._orbit0.distance
    finally:
        w.close()


def _row(pv, name):
    """The frame coordinates of a panel row (from the core's hit regions)."""
    pv.frame()
    for (x, y, w, h), what in pv._hits:
        if what == ("control", name):
            return x + 30, y + h // 2
    raise KeyError(name)


# ---- the desktop window under a virtual X server ------------------------------------------------
def _xwd(path):
    """An xwd dump (32-bit pixels) as H×W×3 RGB."""
    import struct
    b = Path(path).read_bytes()
    h = struct.unpack(">25I", b[:100])
    W, H, bpl, order = h[4], h[5], h[12], h[7]
    px = np.frombuffer(b[h[0] + h[19] * 12:][:bpl * H], "<u4" if order == 0 else ">u4").reshape(H, -1)[:, :W]
    return np.stack([((px & m) >> ((m & -m).bit_length() - 1)).astype(np.uint8) for m in h[14:17]], axis=-1)




@pytest.mark.process
def test_window_under_xvfb(preview_window, small_toml, tmp_path, gl_ctx):
    with preview_window(str(small_toml), "--size", *map(str, SIZE), "--log-frames", "--no-timings",
                        cwd=tmp_path) as (app, env):
        import queue
        import threading
        out, lines = queue.Queue(), []
        threading.Thread(target=lambda: [out.put(line) for line in app.stdout], daemon=True).start()

        def wait_for(text, timeout=60):
            t0 = time.monotonic()
            while time.monotonic() - t0 < timeout:
                try:
                    line = out.get(timeout=0.5)
                except queue.Empty:
                    continue
                lines.append(line)
                if text in line and "quality=full" in line:
                    return line
            raise AssertionError(f"no frame with {text!r} within {timeout} s: {lines}")

        def window_pixels():
            wid = subprocess.run(["xdotool", "search", "--name", "glsim preview"], env=env, capture_output=True,
                                 text=True).stdout.split()[0]
            dump = tmp_path / "w.xwd"
            subprocess.run(["xwd", "-id", wid, "-silent", "-out", str(dump)], env=env, check=True)
            return wid, _xwd(dump)

        def xdo(*args):
            subprocess.run(["xdotool", *args], env=env, check=True)

        wait_for("step=0")
        wid, shown = window_pixels()
        with Preview(small_toml, size=SIZE, ctx=gl_ctx) as pv:
            pv.show_timings = False
            assert np.array_equal(shown, pv.refine())
            xdo("key", "--window", wid, "Right")                           # a real key press: next load step
            wait_for("step=1")
            pv.set("step", 1)
            assert np.array_equal(window_pixels()[1], pv.refine())
            x, y = _row(pv, "lighting")                                    # a real click on the panel
            xdo("mousemove", "--window", wid, str(x), str(y), "click", "1")
            wait_for("lighting=True")
            pv.set("lighting", True)
            assert np.array_equal(window_pixels()[1], pv.refine())
            xdo("key", "--window", wid, "e")                               # a key toggles the edges overlay
            wait_for("overlays=edges")
            xdo("key", "--window", wid, "Right")
            wait_for("step=2")
            pv.set("overlay:edges", True)
            pv.set("step", 2)
            assert np.array_equal(window_pixels()[1], pv.refine())
        # q quits (the window is gone before xdotool sends the key release, so its status is not checked)
        subprocess.run(["xdotool", "key", "--window", wid, "q"], env=env, capture_output=True)
        assert app.wait(30) == 0


@pytest.mark.tools
# ---- glsim bench preview ------------------------------------------------------------------------------
@pytest.mark.process
def test_reduced_bench_never_writes_the_committed_results(tmp_path):
    results = ROOT / "bench/results/preview.json"
    before = results.read_bytes() if results.is_file() else None
    r = _glsim("bench", "preview", "--size", 160, 122, "--reps", 3, "--frame", 640, 400, "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    report = json.loads((tmp_path / "preview.json").read_text())
    assert report["rows"][0]["drag_camera"]["n"] == 3 and report["machine"]["gl"]["renderer"]
    assert "| bulge pair" in (tmp_path / "preview.md").read_text()
    r = _glsim("bench", "preview", "--size", 160, 122, "--reps", 3, "--out", "bench/results")
    assert r.returncode == 2 and "overwrite the committed" in r.stderr
    assert (results.read_bytes() if results.is_file() else None) == before


THREADS = """
import threading, numpy as np
from glsim.scene import bulge_scene
from glsim.workflows.preview import Preview
pv = Preview(bulge_scene(size=(160, 122), steps=1), size=(640, 400))   # its own EGL context
out = {}
t = threading.Thread(target=lambda: out.update(a=pv.refine().copy()))
t.start(); t.join()
pv.set("step", 1)                     # back in the thread that made it
t = threading.Thread(target=lambda: out.update(b=pv.refine().copy())); t.start(); t.join()
c = pv.refine()
assert np.array_equal(out["b"], c) and not np.array_equal(out["a"], c)
pv.close()
print("ok")
"""


@pytest.mark.process
def test_own_context_draws_from_any_thread():
    """Jupyter calls get_frame from another thread than the cell that made the widget."""
    r = subprocess.run([sys.executable, "-c", THREADS], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


# ---- a real browser: JupyterLab on localhost, headless Chromium ----------------------------------
BROWSER_NB = """from glsim.scene import bulge_scene
from glsim.workflows.preview import Widget
w = Widget(bulge_scene(size=(320, 244), steps=2), size=(853, 480))
w.core.show_timings = False
w.quality = 100
w.core.set("step", 1)
w.core.set("overlay:edges", True)
w"""


def _chromium():
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.process
def test_widget_in_jupyterlab_with_headless_chromium(tmp_path, gl_ctx):
    """The notebook runs in JupyterLab; Chromium shows the widget; the frame image in the page
    equals the offscreen frame of the same settings (lossless PNG frames)."""
    import socket
    import urllib.request
    lab_bin = Path(sys.executable).with_name("jupyter-lab")
    if _chromium() is None or not lab_bin.exists():
        pytest.skip("needs Debian's chromium and jupyterlab (make test installs both)")
    websocket = pytest.importorskip("websocket")

    def free_port():
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]

    nb = {"cells": [{"cell_type": "code", "id": "c0", "metadata": {}, "execution_count": None, "outputs": [],
                     "source": BROWSER_NB.splitlines(True)}],
          "metadata": {"kernelspec": {"display_name": "Python 3", "language": "python", "name": "python3"}},
          "nbformat": 4, "nbformat_minor": 5}
    (tmp_path / "widget.ipynb").write_text(json.dumps(nb))
    port, dport, token = free_port(), free_port(), "glsim-preview-test"
    env = {**os.environ, "PATH": f"{lab_bin.parent}:{os.environ['PATH']}", "JUPYTER_CONFIG_DIR": str(tmp_path / "cfg"),
           "JUPYTER_DATA_DIR": str(tmp_path / "data"), "JUPYTER_RUNTIME_DIR": str(tmp_path / "run")}
    procs = [subprocess.Popen([str(lab_bin), "--no-browser", f"--port={port}", "--ip=127.0.0.1",
                               f"--IdentityProvider.token={token}", "--LabApp.expose_app_in_browser=True",
                               f"--ServerApp.root_dir={tmp_path}", "--allow-root"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=tmp_path)]
    try:
        deadline = time.monotonic() + 90
        while True:
            try:
                urllib.request.urlopen(f"http://127.0.0.1:{port}/api/status?token={token}", timeout=1)
                break
            except OSError:
                assert time.monotonic() < deadline, "JupyterLab did not start"
                time.sleep(0.3)
        procs.append(subprocess.Popen([_chromium(), "--headless=new", "--no-sandbox", "--disable-gpu",
                                       f"--remote-debugging-port={dport}", "--window-size=1600,1200",
                                       f"--user-data-dir={tmp_path / 'chrome'}", "about:blank"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        while True:
            try:
                tabs = json.load(urllib.request.urlopen(f"http://127.0.0.1:{dport}/json", timeout=1))
                break
            except OSError:
                assert time.monotonic() < deadline, "Chromium did not start"
                time.sleep(0.3)
        ws = websocket.create_connection([t for t in tabs if t["type"] == "page"][0]["webSocketDebuggerUrl"],
                                         timeout=60)
        ids = iter(range(1, 10**6))

        def js(expr):
            i = next(ids)
            ws.send(json.dumps({"id": i, "method": "Runtime.evaluate",
                                "params": {"expression": expr, "awaitPromise": True, "returnByValue": True}}))
            while True:
                m = json.loads(ws.recv())
                if m.get("id") == i:
                    return m["result"].get("result", {}).get("value")

        js(f"location.href = 'http://127.0.0.1:{port}/lab/tree/widget.ipynb?token={token}'")
        kernel = ("(() => { const a = window.jupyterapp; const w = a && Array.from(a.shell.widgets('main'))"
                  ".find(x => x.sessionContext); "
                  "const k = w && w.sessionContext && w.sessionContext.session && w.sessionContext.session.kernel; "
                  "return !!(k && k.status === 'idle' && document.querySelector('.jp-Notebook')); })()")
        while js(kernel) is not True:
            assert time.monotonic() < deadline + 60, "the notebook's kernel did not start"
            time.sleep(0.5)
        js("(() => { const a = window.jupyterapp; const w = Array.from(a.shell.widgets('main')).find(x => x.sessionContext); "
           "a.shell.activateById(w.id); return a.commands.execute('notebook:run-all-cells'); })()")
        image = ("(() => { const i = document.querySelector('.jp-OutputArea img'); if (!i || !i.complete || "
                 "!i.naturalWidth) return null; const c = document.createElement('canvas'); c.width = i.naturalWidth; "
                 "c.height = i.naturalHeight; c.getContext('2d').drawImage(i, 0, 0); return [i.src, c.toDataURL('image/png')]; })()")
        import base64
        import io
        import imageio.v3 as iio
        expected, last, shown = {}, None, None
        end = time.monotonic() + 120
        while time.monotonic() < end:
            got = js(image)
            if got and got[0] == last:          # the same frame for a while: the refined one
                shown = iio.imread(io.BytesIO(base64.b64decode(got[1].split(",", 1)[1])))[..., :3]
                size = (shown.shape[1], shown.shape[0])
                if size not in expected:          # the view may resize the frame to its own size
                    with Preview(small_scene(), size=size, ctx=gl_ctx) as pv:
                        pv.show_timings = False
                        pv.set("step", 1)
                        pv.set("overlay:edges", True)
                        expected[size] = pv.refine()
                if np.array_equal(shown, expected[size]):
                    break
            last = got[0] if got else None
            time.sleep(1.5)
        assert shown is not None, "no widget frame appeared in the page"
        iio.imwrite(tmp_path / "browser.png", shown)
        assert np.array_equal(shown, expected[(shown.shape[1], shown.shape[0])])
        ws.close()
    finally:
        for p in reversed(procs):
            p.terminate()
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                p.kill()
