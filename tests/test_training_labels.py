"""The training labels of glsim.workflows.training.labels against independent references: the
images themselves (a warp), the labels' own inverse, OpenCV's triangulation, the imposed field,
a split mesh and a stereo occlusion worked out by hand."""
import dataclasses

import cv2
import numpy as np
import pytest
from scipy import ndimage

from glsim.errors import SceneError
from glsim.io.fe import specimen_mesh
from glsim.io.truth import mesh_geometry
from glsim.render import Renderer
from glsim.scene import Plate, Speckle
from glsim.scene import mesh as meshmod
from glsim.scene.camera import Distortion, project_camera_frame, rotation_xyz
from glsim.scene.locate import points_truth
from glsim.scene.tables import Pose, Stereo
from glsim.workflows.training import labels as lb
from glsim.workflows.training.labels import pair_labels
from tests._plates import plate_scene

pytestmark = pytest.mark.workflow   # the compute-stage rerun of the GL tier leaves these out (docs/testing.md)

BACKENDS = ["cpu", pytest.param("gl", marks=pytest.mark.gl)]
UP = 4    # the warp test's reference: camera 0 with UP × its pixels


def _scene(size=(96, 96), fx=1800.0, **kw):
    """A 16 × 16 mm plate 300 mm before camera "c" (0.17 mm/px), a smooth speckle (dots of 6 px with
    3-px edges: interpolable at a quarter pixel)."""
    kw.setdefault("speckle", Speckle(dot_diameter_px=6.0, edge_px=3.0, seed=3))
    return plate_scene(size, fx=fx, plate=Plate(width=16, height=16, nx=8, ny=8, translations=((0.1, 0.2, 0.0),)), **kw)


def _smooth(mesh):
    """``mesh`` with a smooth non-uniform step 1 (mm): stretch, shear, rotation, bending, out of plane
    — up to 3 px."""
    x, y = mesh.nodes[:, 0], mesh.nodes[:, 1]
    u = np.stack([0.02 * x - 0.015 * y + 0.0015 * x * x + 0.21, 0.015 * x + 0.01 * y - 0.001 * x * y - 0.13,
                  0.002 * (x * x + y * y)], 1)
    return meshmod.with_displacements(mesh, [u])


def _pair(scene, mesh, backend, ctx, cams=("c",), extra=()):
    """The truths and images of ``cams`` at steps 0 and 1, and the Results of ``extra`` at step 0."""
    with Renderer(dataclasses.replace(scene, render=dataclasses.replace(scene.render, backend=backend)),
                  ctx=ctx, mesh=mesh) as r:
        res = {(c, s): r.render(c, step=s, truth=True) for c in cams for s in (0, 1)}
        more = [r.render(c, step=0, truth=True) for c in extra]
    return ({c: res[c, 0].truth for c in cams}, {c: res[c, 1].truth for c in cams},
            {k: v.image.astype(np.float64) for k, v in res.items()}, more)


def _grid(H, W):
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    return u, v


@pytest.mark.parametrize("backend", BACKENDS)
def test_flow_warps_the_reference_onto_the_deformed_image(backend, ctx_for):
    """def(p) = ref(p + flow(p)): the reference state rendered UP times finer (camera 0 with UP·fx,
    UP·c: its pixel U samples camera 0's image at U / UP) and interpolated bilinearly (cv2.remap) at
    UP·(p + flow) gives the deformed image within the interpolation error: ⅛ (max |I_UU| + max |I_VV|)
    in fine pixels (the global maxima of the second differences: dots cross the grid at every phase),
    plus remap's 1/32-px position grid, ≤ 1/64 px per axis times the largest first differences.
    A flow 0.2 px off breaks it at a fifth of the pixels."""
    base = _scene()
    c0 = base.cameras[0]
    fine = dataclasses.replace(c0, name="fine", size=(UP * c0.width, UP * c0.height), fx=UP * c0.fx, fy=UP * c0.fy,
                               cx=UP * c0.cx, cy=UP * c0.cy)
    scene = dataclasses.replace(base, cameras=(c0, fine))
    mesh = _smooth(specimen_mesh(scene))
    ref, dfm, images, (hi,) = _pair(scene, mesh, backend, ctx_for(backend), extra=("fine",))
    L = pair_labels(scene, 1, ref, dfm, mesh=mesh)
    flow, valid = L["flow0"].astype(np.float64), L["mask_flow0"].astype(bool)
    assert valid.sum() > 0.97 * dfm["c"].mask.sum()      # nothing occluded, nothing split: all but the edge
    img = hi.image.astype(np.float64)
    inside = ndimage.minimum_filter(hi.truth.mask, size=3)       # a fine pixel and its 8 neighbours on the plate
    d2 = np.abs(np.diff(img, 2, axis=1))[inside[:, 1:-1]].max() + np.abs(np.diff(img, 2, axis=0))[inside[1:-1]].max()
    d1 = np.abs(np.diff(img, axis=1))[inside[:, 1:]].max() + np.abs(np.diff(img, axis=0))[inside[1:]].max()
    bound = d2 / 8 + d1 / 64
    H, W = valid.shape
    u, v = _grid(H, W)

    def exceed(f):
        U, V = UP * (u + f[..., 0]), UP * (v + f[..., 1])
        i, j = np.floor(U).astype(int), np.floor(V).astype(int)
        cell = valid & (i >= 0) & (j >= 0) & (i < UP * W - 1) & (j < UP * H - 1)
        cell[cell] &= inside[j[cell], i[cell]] & inside[j[cell] + 1, i[cell] + 1]
        warped = cv2.remap(img.astype(np.float32), U.astype(np.float32), V.astype(np.float32), cv2.INTER_LINEAR)
        assert cell.sum() > 0.9 * valid.sum()
        return np.abs(warped - images["c", 1])[cell] > bound

    assert not exceed(flow).any()
    assert exceed(flow + [0.2, 0.0]).mean() > 0.2
    assert exceed(flow + [0.0, -0.2]).mean() > 0.2


@pytest.mark.parametrize("backend", BACKENDS)
def test_labels_are_the_truth_projected(backend, ctx_for):
    """flow0 is the projection (glsim.scene.camera.project_camera_frame) of the deformed truth's
    X_undeformed minus the pixel, forward0 that of the deformed position of each reference pixel's
    point located by ray casting (glsim.scene.locate.points_truth), uvw that point's displacement —
    to float32's rounding."""
    scene = _scene(distortion=Distortion(k1=-0.3, p2=0.002))
    mesh = _smooth(specimen_mesh(scene))
    ref, dfm, _, _ = _pair(scene, mesh, backend, ctx_for(backend))
    L = pair_labels(scene, 1, ref, dfm, mesh=mesh)
    cam = scene.cameras[0]
    H, W = ref["c"].mask.shape
    p = np.stack(_grid(H, W), -1)
    m = L["mask_flow0"].astype(bool)
    q, ok = project_camera_frame(dfm["c"].X_undeformed[m], cam)
    assert ok.all() and m.sum() > 0.97 * dfm["c"].mask.sum()
    _stored(L["flow0"][m], q - p[m])
    m = L["mask_forward0"].astype(bool)
    pt = points_truth(mesh_geometry(mesh), cam, p[m], 1)
    assert pt.valid.all() and np.array_equal(pt.element, ref["c"].element[m])
    q, _ = project_camera_frame(pt.X_deformed, cam)
    _stored(L["forward0"][m], q - p[m])
    m = L["mask_uvw"].astype(bool)           # (also where the point leaves the deformed image)
    assert np.array_equal(m, ref["c"].mask)
    _stored(L["uvw"][m], points_truth(mesh_geometry(mesh), cam, p[m], 1).displacement)
    for k in ("flow0", "forward0", "uvw"):
        assert L[k].dtype == np.float32 and not L[k][~L["mask_" + k].astype(bool)].any()


def test_quadratic_elements_are_labelled_by_their_own_shape_functions():
    """A curved Q8 surface (tests/test_quadratic.py's paraboloid, moved and bent at step 1): flow0 is
    the projection of the deformed truth's X_undeformed, uvw the ray-cast point's displacement."""
    from tests.test_quadratic import scene, surface_mesh

    mesh, sc = surface_mesh("quad8"), scene()
    with Renderer(sc, "cpu", mesh=mesh) as r:
        ref, dfm = r.render(0, 0, truth=True).truth, r.render(0, 1, truth=True).truth
    cam = sc.cameras[0]
    L = pair_labels(sc, 1, {cam.name: ref}, {cam.name: dfm}, mesh=mesh)
    p = np.stack(_grid(*ref.mask.shape), -1)
    m = L["mask_flow0"].astype(bool)
    assert m.sum() > 0.9 * dfm.mask.sum() > 1000
    _stored(L["flow0"][m], project_camera_frame(dfm.X_undeformed[m], cam)[0] - p[m])
    m = L["mask_uvw"].astype(bool)
    assert np.array_equal(m, ref.mask)
    _stored(L["uvw"][m], points_truth(mesh_geometry(mesh), cam, p[m], 1).displacement)


def _ulp(a):
    """float32's unit in the last place at ``a``, per value."""
    a = np.abs(np.asarray(a, np.float32))
    return (np.nextafter(a, np.float32(np.inf)) - a).astype(np.float64)


def _stored(got, want):
    """``got`` (float32) is ``want`` (float64, made another way) rounded to float32: within half its
    ulp, and 1e-9 for the two float64 computations' own rounding."""
    err = np.abs(got.astype(np.float64) - want)
    assert (err <= _ulp(want) / 2 + 1e-9).all(), float(err.max())


@pytest.mark.parametrize("backend", BACKENDS)
def test_flow_inverts_forward(backend, ctx_for):
    """flow(p + forward(p)) = −forward(p): flow interpolated bilinearly (float64) at the forward
    position, within the interpolation error ⅛ (max |flow_uu| + max |flow_vv|) (its second
    differences over the valid pixels) and the labels' float32 rounding."""
    scene = _scene()
    mesh = _smooth(specimen_mesh(scene))
    ref, dfm, _, _ = _pair(scene, mesh, backend, ctx_for(backend))
    L = pair_labels(scene, 1, ref, dfm, mesh=mesh)
    fw, fl = L["forward0"].astype(np.float64), L["flow0"].astype(np.float64)
    mf, mb = L["mask_forward0"].astype(bool), L["mask_flow0"].astype(bool)
    H, W = mf.shape
    u, v = _grid(H, W)
    U, V = u + fw[..., 0], v + fw[..., 1]
    i, j = np.floor(U).astype(int), np.floor(V).astype(int)
    ok = mf & (i >= 0) & (j >= 0) & (i < W - 1) & (j < H - 1)
    cell = mb.copy()                                         # the 2×2 cell right and below valid
    cell[:-1, :-1] &= mb[1:, :-1] & mb[:-1, 1:] & mb[1:, 1:]
    ok[ok] &= cell[j[ok], i[ok]]
    assert ok.sum() > 0.95 * mf.sum()
    d2 = 0.0
    for axis in (0, 1):
        both = ndimage.minimum_filter1d(mb, 3, axis=axis)
        d2 += np.abs(np.diff(fl, 2, axis=axis))[both[1:-1] if axis == 0 else both[:, 1:-1]].max()
    back = np.stack([ndimage.map_coordinates(fl[..., k], [V[ok], U[ok]], order=1) for k in (0, 1)], -1)
    bound = d2 / 8 + 4 * _ulp(np.abs(fw).max() + W)
    assert np.abs(back + fw[ok]).max() <= bound
    assert bound < 2e-3


def _stereo(distortion=None, **kw):
    """Camera "c" and, 60 mm to its right turned 11° towards the plate, camera "d"."""
    return _scene(size=(128, 112), distortion=distortion or Distortion(),
                  second={"name": "d", "pose": Pose(stereo=Stereo(-60.0, 0.0, 0.0, 0.0, 11.0, 0.0))}, **kw)


@pytest.mark.parametrize("backend", BACKENDS)
def test_disparity_triangulates_to_the_truth(backend, ctx_for):
    """(p, p + disparity) undistorted (cv2.undistortPoints, to 1e-14) and triangulated
    (cv2.triangulatePoints) with the rig's two cameras give the truth's X_undeformed (reference) and
    X_deformed (deformed) at camera 0's pixel, within what the disparity's float32 rounding moves
    it: |δd| ≤ ulp/√2 px, which moves the point by Z/f·|δd| across the ray and Z²/(f B)·|δd| along it
    (B the baseline); the bound takes 2 ulp for the rig's convergence and the undistortion."""
    dist = Distortion(k1=-0.25, k2=0.1, p1=0.001)
    scene = _stereo(dist)
    mesh = specimen_mesh(scene)
    ref, dfm, _, _ = _pair(scene, mesh, backend, ctx_for(backend), cams=("c", "d"))
    L = pair_labels(scene, 1, ref, dfm, mesh=mesh)
    c0, c1 = scene.cameras
    R, t = c1.rotation @ c0.rotation.T, c1.translation - c1.rotation @ c0.rotation.T @ c0.translation
    B = float(np.linalg.norm(t))
    P0, P1 = np.hstack([np.eye(3), np.zeros((3, 1))]), np.hstack([R, t[:, None]])
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    for state, truths in (("ref", ref), ("def", dfm)):
        m = L[f"mask_disparity_{state}"].astype(bool)
        assert m.sum() > 0.95 * truths["c"].mask.sum()
        d = L[f"disparity_{state}"][m].astype(np.float64)
        H, W = m.shape
        p = np.stack(_grid(H, W), -1)[m]
        x0 = cv2.undistortPoints(p[:, None], c0.K, dist.coeffs, criteria=crit)[:, 0]
        x1 = cv2.undistortPoints((p + d)[:, None], c1.K, dist.coeffs, criteria=crit)[:, 0]
        Xh = cv2.triangulatePoints(P0, P1, x0.T.copy(), x1.T.copy())
        X = (Xh[:3] / Xh[3]).T
        truth = truths["c"].X_undeformed if state == "ref" else truths["c"].X_deformed
        Z = truth[m][:, 2]
        err = np.linalg.norm(X - truth[m], axis=1)
        bound = (Z / c0.fx) * (Z / B + 1) * 2 * _ulp(np.abs(d).max()) + 1e-9
        assert (err <= bound).all(), float((err / bound).max())


@pytest.mark.parametrize("angles", [(0.0, 0.0, 0.0), (8.0, -12.0, 20.0)])
def test_uvw_is_the_imposed_translation(angles):
    """A rigidly translated plate: uvw is the translation in camera 0's frame, to float32, everywhere
    the plate is seen. Camera 0 turned by R and the plate by Rᵀ (its translation, given in its own
    frame, turned with it): the world sees Rᵀ·shift, camera 0 shift."""
    shift = np.array([0.37, -0.21, 0.5])
    R = rotation_xyz(*angles)
    placed = Pose(R=tuple(map(tuple, R.T)), t=tuple(R.T @ [0.0, 0.0, 300.0]))   # seen as unturned, 300 mm ahead
    scene = plate_scene((96, 80), fx=1800.0, R=R, specimen_pose=placed, backend="cpu",
                        plate=Plate(width=16, height=16, nx=4, ny=4, translations=(tuple(shift),)))
    with Renderer(scene) as r:
        ref, dfm = r.render("c", 0, truth=True).truth, r.render("c", 1, truth=True).truth
    L = pair_labels(scene, 1, {"c": ref}, {"c": dfm})
    m = L["mask_uvw"].astype(bool)
    assert np.array_equal(m, ref.mask) and m.sum() > 1000
    want = shift
    _stored(L["uvw"][m], np.broadcast_to(want, (m.sum(), 3)))
    assert L["uvw"].dtype == np.float32 and not L["uvw"][~m].any() and L["mask_uvw"].dtype == np.uint8


def _split_mesh(slide):
    """Two 8 × 16 mm halves meeting at x = 0 (their nodes there doubled, none shared), 300 mm before
    camera 0; the right half moves by ``slide`` (mm) at step 1."""
    left, right = meshmod.plate(8, 16, 4, 8, center=(-4, 0, 300)), meshmod.plate(8, 16, 4, 8, center=(4, 0, 300))
    n = len(left.nodes)
    nodes = np.vstack([left.nodes, right.nodes])
    quads = np.vstack([left.quads, right.quads + n])
    mesh = meshmod.Mesh(nodes, quads, np.arange(1, 2 * n + 1), np.arange(1, len(quads) + 1))
    u = np.zeros_like(nodes)
    u[n:] = slide
    return meshmod.with_displacements(mesh, [u])


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_split_is_masked_and_nothing_else(backend, ctx_for):
    """Two plate halves sharing no node, the right one slid 0.6 px along the split and opened
    0.36 px: the two columns either side of the split (x = 0 at u = cx = 55.5 in both states: the
    opening stays between pixel centres) are masked in every label, in the rows where both are
    seen; every other covered pixel is valid (the plate lies inside the image in both states). The
    same halves not moved apart are masked along the split too (a split is a split)."""
    scene = _scene(size=(112, 112))
    for slide in ((0.06, 0.1, 0.0), (0.0, 0.0, 0.0)):
        mesh = _split_mesh(slide)
        ref, dfm, _, _ = _pair(scene, mesh, backend, ctx_for(backend))
        L = pair_labels(scene, 1, ref, dfm, mesh=mesh)
        for key, truth in (("flow0", dfm["c"]), ("forward0", ref["c"]), ("uvw", ref["c"])):
            valid = L["mask_" + key].astype(bool)
            seam = np.zeros_like(valid)
            seam[:, 55:57] = (truth.mask[:, 55] & truth.mask[:, 56])[:, None]   # both sides seen in that row
            assert seam.sum() > 150
            assert np.array_equal(valid, truth.mask & ~seam), key
    assert np.abs(L["forward0"][L["mask_forward0"] > 0]).max() < 1e-9     # (not moved: only rounding)


def test_jumps_flag_the_pairs_beyond_a_smooth_field():
    """The jump rule alone: a field curved at 0.1 px/px² (under SMOOTH_CURVATURE) with a 0.2-px step
    between columns 20 and 21 flags exactly those columns; the curvature alone flags nothing."""
    H, W = 30, 40
    u, v = _grid(H, W)
    smooth = np.stack([0.05 * u ** 2 - 0.03 * v ** 2 + 0.5 * u, 0.02 * u * v + 0.05 * v ** 2])
    assert not lb._jumps(smooth.astype(np.float32)).any()
    stepped = smooth + np.where(u > 20.5, 0.2, 0.0)[None] * np.array([0.6, 0.8])[:, None, None]
    flags = lb._jumps(stepped.astype(np.float32))
    want = np.zeros((H, W), bool)
    want[:, 20:22] = True
    assert np.array_equal(flags, want)
    holes = stepped.copy()
    holes[:, :, 19] = np.nan           # a missing column beside the step: the other side still decides
    want[:, 19] = False
    assert np.array_equal(lb._jumps(holes.astype(np.float32)), want & ~np.isnan(holes[0]))


def _occluder_mesh(strip_moves=(0.05, 0.02, 0.0)):
    """A 16 × 16 mm plate 300 mm before camera 0 and, 10 mm in front of it, a 4 × 16 mm strip at
    x ∈ [−2, 2]: camera 1, 60 mm to the right, sees the strip's shadow on the plate at x ∈ [−4.1, −0.1].
    At step 1 both move by (0.05, 0.02, 0) mm, or the strip alone by ``strip_moves``."""
    back, strip = meshmod.plate(16, 16, 8, 8, center=(0, 0, 300)), meshmod.plate(4, 16, 2, 8, center=(0, 0, 290))
    n = len(back.nodes)
    mesh = meshmod.Mesh(np.vstack([back.nodes, strip.nodes]), np.vstack([back.quads, strip.quads + n]),
                        np.arange(1, n + len(strip.nodes) + 1), np.arange(1, len(back.quads) + len(strip.quads) + 1))
    u = np.tile(strip_moves, (len(mesh.nodes), 1))
    if strip_moves != (0.05, 0.02, 0.0):
        u[:n] = 0.0
    return meshmod.with_displacements(mesh, [u]), len(back.quads)


@pytest.mark.parametrize("backend", BACKENDS)
def test_occlusion_between_the_states_is_masked(backend, ctx_for):
    """The strip alone moves 1 mm (6 px) across the still plate: plate points camera 0 sees in one
    state and not in the other (the ray from the camera centre to the point crosses the strip's
    outline in that state, worked out by hand) are masked in that state's label (forward0 for
    those hidden at the step, flow0 for those hidden at step 0), more than a pixel inside; those
    seen in both, more than 1.5 px from the strip's outline in either state, are valid."""
    scene = _scene(size=(128, 112))
    mesh, n_back = _occluder_mesh(strip_moves=(1.0, 0.0, 0.0))
    ref, dfm, _, _ = _pair(scene, mesh, backend, ctx_for(backend))
    L = pair_labels(scene, 1, ref, dfm, mesh=mesh)
    margin = 300.0 / scene.cameras[0].fx           # a pixel's footprint on the plate, mm

    def behind(X, shift):
        """How far (mm, on the strip) inside the strip's outline, moved by ``shift`` in x, the ray
        from camera 0's centre to X crosses the strip's plane: > 0 hidden."""
        cross = X * (290.0 / X[..., 2])[..., None]
        return np.minimum(2.0 - np.abs(cross[..., 0] - shift), 8.0 - np.abs(cross[..., 1]))

    for key, t, other_shift, own_shift in (("forward0", ref["c"], 1.0, 0.0), ("flow0", dfm["c"], 0.0, 1.0)):
        back = t.mask & (t.element < n_back)
        X = t.X_undeformed                           # (the plate does not move)
        there, here = behind(X, other_shift), behind(X, own_shift)
        valid = L["mask_" + key].astype(bool)
        hidden = back & (there > margin)
        seen = back & (there < -1.5 * margin) & (here < -1.5 * margin)
        seen &= ~ndimage.binary_dilation(t.mask & (t.element >= n_back), iterations=2)
        assert hidden.sum() > 300 and seen.sum() > 3000
        assert not valid[hidden].any(), key
        assert valid[seen].all(), key


@pytest.mark.parametrize("backend", BACKENDS)
def test_stereo_occlusion_is_masked(backend, ctx_for):
    """Points of the back plate that camera 0 sees and camera 1 does not (the strip lies on the segment
    from the point to camera 1's centre, worked out by hand) are masked in the disparities, more
    than a pixel's footprint inside the shadow; points camera 1 sees, more than 1.5 px from the
    shadow's edge, inside camera 1's image and off the strip's outline in camera 0, are valid."""
    scene = _stereo()
    mesh, n_back = _occluder_mesh()
    ref, dfm, _, _ = _pair(scene, mesh, backend, ctx_for(backend), cams=("c", "d"))
    L = pair_labels(scene, 1, ref, dfm, mesh=mesh)
    c0, c1 = scene.cameras
    centre = c1.center                                  # world = camera 0's frame here
    mm_per_px = 300.0 / c0.fx
    for state, truths in (("ref", ref), ("def", dfm)):
        t = truths["c"]
        X = t.X_undeformed if state == "ref" else t.X_deformed
        back = t.mask & (t.element < n_back)
        shift = np.array([0.05, 0.02, 0.0]) if state == "def" else np.zeros(3)
        s = (290.0 - X[..., 2]) / (centre[2] - X[..., 2])          # where the segment crosses the strip's plane
        cross = X + s[..., None] * (centre - X)
        x_rel, y_rel = cross[..., 0] - shift[0], cross[..., 1] - shift[1]
        # signed distance (mm, on the strip) of the crossing inside the strip's outline: > 0 occluded
        inside = np.minimum(2.0 - np.abs(x_rel), 8.0 - np.abs(y_rel))
        margin = mm_per_px                  # a pixel's footprint, ≈ the same on the strip's plane (290 vs 300 mm)
        valid = L[f"mask_disparity_{state}"].astype(bool)
        hidden = back & (inside > margin)
        seen = back & (inside < -1.5 * margin)
        outline = ndimage.binary_dilation(t.mask & (t.element >= n_back), iterations=2)
        q = cv2.projectPoints(X[seen].reshape(-1, 1, 3), cv2.Rodrigues(c1.rotation)[0], c1.translation, c1.K,
                              None)[0][:, 0]
        seen[seen] = (q >= 1).all(axis=1) & (q <= np.array(c1.size) - 2).all(axis=1)   # inside camera 1's image
        assert hidden.sum() > 300 and seen.sum() > 2000
        assert not valid[hidden].any(), state
        assert valid[seen & ~outline].all(), state


def test_bad_input_is_refused_by_name():
    scene = _scene()
    with Renderer(scene, backend="cpu") as r:
        ref, dfm = r.render("c", 0, truth=True).truth, r.render("c", 1, truth=True).truth
    with pytest.raises(SceneError, match=r"^ref: holds cameras \['c'\], deformed \[\]"):
        pair_labels(scene, 1, {"c": ref}, {})
    with pytest.raises(SceneError, match=r"^step: 5 is not a load step"):
        pair_labels(scene, 5, {"c": ref}, {"c": dfm})
    with pytest.raises(SceneError, match=r"^deformed\['c'\]: is a ndarray, not a Truth"):
        pair_labels(scene, 1, {"c": ref}, {"c": dfm.mask})
    with pytest.raises(SceneError, match=r"^camera: no camera named 'x'"):
        pair_labels(scene, 1, {"x": ref}, {"x": dfm})
    with pytest.raises(SceneError, match=r"^ref\['c'\]: names element 63; the specimen has 1"):
        pair_labels(scene, 1, {"c": ref}, {"c": dfm}, mesh=meshmod.with_displacements(meshmod.plate(1, 1, 1, 1),
                                                                                      [np.zeros((4, 3))]))
    small = dataclasses.replace(scene, cameras=(dataclasses.replace(scene.cameras[0], size=(64, 64)),))
    with pytest.raises(SceneError, match=r"^ref\['c'\]: is 96 × 96 px, camera 'c' 64 × 64"):
        pair_labels(small, 1, {"c": ref}, {"c": dfm})
