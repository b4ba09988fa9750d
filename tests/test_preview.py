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
from glsim.errors import SceneError
from glsim.render import Renderer
from glsim.scene import bulge_scene, demo_effects, load_scene
from glsim.scene.camera import project
from glsim.workflows.preview import Preview
from glsim.workflows.preview import overlays as ov
from glsim.workflows.preview.core import display_grey
from glsim.workflows.preview.sceneio import reference_key, same_reference
from glsim.stages.reference import make_reference, specimen_mesh

pytestmark = pytest.mark.gl
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
    expect = {"stereo_angle": ({"pose", "speckle"}, 36.0), "distance": ({"pose", "speckle"}, 650.0),
              "target_x": ({"pose", "speckle"}, 5.0), "target_y": ({"pose", "speckle"}, -4.0),
              "target_z": ({"pose", "speckle"}, 10.0), "focal_length": ({"intrinsics", "optics", "speckle"}, 33.0),
              "f_number": ({"optics"}, 8.0), "focus_distance": ({"optics"}, 590.0), "ambient": ({"lighting"}, 0.05),
              "light_intensity": ({"lighting"}, 0.5), "light_x": ({"lighting"}, -120.0),
              "light_y": ({"lighting"}, -150.0), "light_z": ({"lighting"}, 50.0), "noise_sigma": ({"noise"}, 1.0),
              "speckle_size": ({"speckle"}, 6.0), "speckle_seed": ({"speckle"}, 3), "mode": ({"render"}, "q4")}
    for name, (what, value) in expect.items():
        before, uploads, ref = pv.scene, pv.reference_uploads, pv.renderer.reference
        assert pv.set(name, value), pv.messages
        assert sections(before, pv.scene) == what, name
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


def test_pose_change_keeps_the_speckle_and_renders_like_the_saved_scene(fresh, tmp_path):
    pv = fresh
    pv.refine()
    textures = dict(pv.renderer.backend._textures)
    for name, value in (("stereo_angle", 34.0), ("distance", 640.0), ("focal_length", 32.0), ("dof", True),
                        ("lighting", True), ("noise", True), ("step", 1)):
        pv.set(name, value)
    pv.refine()
    assert pv.reference_uploads == 1
    assert {k: id(v) for k, v in pv.renderer.backend._textures.items()} == {k: id(v) for k, v in textures.items()}
    path = pv.save(tmp_path / "edited.toml")
    loaded = load_scene(path)
    assert loaded.speckle.camera is not None and loaded.lighting and loaded.optics and loaded.noise
    # the same reference as the preview's, although camera 1 moved
    assert same_reference(reference_key(loaded, pv.mesh.nodes), pv._key)
    for i in range(2):
        np.testing.assert_allclose(offscreen(loaded, i, 1).image, pv.camera_image(i), atol=1e-6, rtol=0)


def test_reference_key_follows_make_reference(gl_ctx):
    scene = small_scene()
    mesh = specimen_mesh(scene)
    key = reference_key(scene, mesh.nodes)
    ref = make_reference(scene, mesh)
    assert key[1] == ref.camera and ref.dots.shape == (ref.camera.height, ref.camera.width)
    assert ref.dots.edge_px == pytest.approx(key[4])
    assert np.median(ref.dots.radii) * 2 == pytest.approx(key[3], rel=0.05)


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
    assert np.array_equal(d["above"], img > 1) and np.array_equal(d["below"], img < 0)
    assert d["above"].sum() > 100
    tile = pv.tile(0)
    assert np.array_equal(np.all(tile[20:] == (255, 30, 30), axis=-1), d["above"][20:])
    assert frame is pv._frame


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
