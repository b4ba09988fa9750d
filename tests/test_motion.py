"""Motion over the exposure and the rolling shutter (glsim/effects/motion.py, docs/motion.md),
checked against closed forms: the average of shifted renders, the box-filtered edge, the
rolling shutter's shear; GL against the oracle; the tables' validation; absent tables cost
nothing.

The scene: a 20 × 15 mm plate 300 mm before a 64 × 48 px camera (fx = 500 px: 1 mm = 5/3 px,
exactly linear, the plate parallel to the image), textured by a reference image in mm."""
from __future__ import annotations

import numpy as np
import pytest

from _plates import plate_scene
from glsim.errors import SceneError
from glsim.effects import motion
from glsim.check import closed_forms, oracle_maps
from glsim.io.images import write_truth
from glsim.io.truth import load as load_truth
from glsim.render import Renderer
from glsim.scene import Plate, Speckle, scene_from_dict
from glsim.scene.optional import row_offsets

Z, FX, SIZE = 300.0, 500.0, (64, 48)
PX_PER_MM = FX / Z
MM_PER_REF_PX = 0.05          # reference pixel: 1/12 camera px


def edge_scene(tmp_path, profile, translations=(), **sections):
    """The plate textured by ``profile(X)`` (grey level of the specimen's X, mm; the reference
    image 440 × 320 px, centred on the plate), linear interpolation (reproduces a linear profile
    exactly), with ``sections`` (exposure, sensor, …)."""
    import tifffile

    W = 440
    X = (np.arange(W) - (W - 1) / 2) * MM_PER_REF_PX
    tifffile.imwrite(tmp_path / "ref.tif", np.tile(profile(X), (320, 1)).astype(np.float32))
    scene = plate_scene(size=SIZE, fx=FX, z=Z, interpolation="linear", base_dir=str(tmp_path),
                        plate=Plate(width=20, height=15, nx=4, ny=3, translations=translations),
                        speckle=Speckle(image="ref.tif", mm_per_px=MM_PER_REF_PX))
    return scene.replace(**sections) if sections else scene


def step_edge(X):
    return (X > 0).astype(float)     # black at X < 0, white at X > 0: the edge at X = 0 (u = cx)


def ramp(X):
    return np.clip(0.5 + X / 8.0, 0, 1)   # grey 0.5 at X = 0, 1/8 per mm (0.075 per camera px)


def render(scene, backend="cpu", step=0, **kw):
    with Renderer(scene, backend) as r:
        return r.render(0, step, **kw)


def test_rigid_translation_is_the_average_of_shifted_renders(tmp_path):
    """velocity v over T with S samples = the mean of the static renders at v·τ_i (the same
    nodes, to the bit), and truth is the mid-exposure (static) truth with the motion range v·T."""
    v, T, S = np.array([300.0, -120.0, 0.0]), 0.01, 5
    taus = motion.sample_offsets(T, S)
    base = edge_scene(tmp_path, step_edge)
    shifted = edge_scene(tmp_path, step_edge, translations=tuple(tuple(v * t) for t in taus))
    with Renderer(shifted, "cpu") as r:
        frames = [r.render(0, k).image.astype(np.float64) for k in range(1, S + 1)]
        still = r.render(0, 0, truth=True).truth
    moving = render(base.replace(exposure={"time": T, "samples": S, "velocity": v.tolist()}), truth=True)
    np.testing.assert_array_equal(moving.image, (sum(frames) / S).astype(np.float32))
    tr = moving.truth
    np.testing.assert_array_equal(tr.element, still.element)
    np.testing.assert_array_equal(tr.X_deformed, still.X_deformed)
    d = tr.uv_end[tr.mask] - tr.uv_start[tr.mask]   # pinhole, plate parallel to the image: exactly v·T·fx/Z
    np.testing.assert_allclose(d, np.broadcast_to(v[:2] * T * PX_PER_MM, d.shape), atol=1e-9)
    path = write_truth(tmp_path / "c_0000_truth.npz", tr.as_dict())     # written and read back with the maps
    np.testing.assert_array_equal(load_truth(path).maps().uv_end, tr.uv_end)


def test_moving_edge_is_the_box_filtered_edge(tmp_path):
    """A black/white edge moving d px during the exposure: the oracle's image is the midpoint
    rule's staircase (1/S)·#{i: u > u_e + v_px·τ_i} wherever the pixel is ≥ 1 reference px from
    every sampled edge, and within 1/(2S) + (1 ref px)/d of the box filter clip((u − u_e)/d + ½, 0, 1)."""
    d, T, S = 8.0, 0.01, 16
    v_px = d / T
    scene = edge_scene(tmp_path, step_edge, exposure={"time": T, "samples": S, "velocity": [v_px / PX_PER_MM, 0, 0]})
    row = render(scene).image[24, 20:44].astype(np.float64)   # inside the plate (u = 15…48)
    u = np.arange(20, 44) - (SIZE[0] - 1) / 2                 # u − u_e
    edges = v_px * motion.sample_offsets(T, S)
    stair = (u[:, None] > edges[None]).mean(axis=1)
    far = np.abs(u[:, None] - edges[None]).min(axis=1) > MM_PER_REF_PX * PX_PER_MM
    assert far.sum() > 15
    np.testing.assert_allclose(row[far], stair[far], atol=1e-6)
    box = np.clip(u / d + 0.5, 0, 1)
    assert np.abs(row - box).max() <= 1 / (2 * S) + MM_PER_REF_PX * PX_PER_MM / d


def test_rolling_shutter_shears_a_translation(tmp_path):
    """Row r is exposed at τ_r = (r − (H − 1)/2)·L: a plate moving at v_px shows the ramp's 0.5
    crossing at u = cx + v_px·τ_r in row r (measured by linear interpolation, exact on a linear
    profile), and row r's truth is displaced by v·τ_r."""
    L, v_px = 1e-4, 1500.0          # 0.15 px per row: 3.5 px from the plate's top to its bottom row
    v = v_px / PX_PER_MM
    scene = edge_scene(tmp_path, ramp, exposure={"velocity": [v, 0, 0]}, sensor={"line_time": L})
    res = render(scene, truth=True)
    H = SIZE[1]
    tau = row_offsets(H, L)
    rows = np.flatnonzero(res.truth.mask.any(axis=1))
    assert len(rows) >= 20
    for r in rows:
        g = res.image[r].astype(np.float64)
        k = np.flatnonzero((g[:-1] < 0.5) & (g[1:] >= 0.5))[0]
        crossing = k + (0.5 - g[k]) / (g[k + 1] - g[k])
        assert crossing == pytest.approx((SIZE[0] - 1) / 2 + v_px * tau[r], abs=1e-4)
    tr = res.truth
    still = render(edge_scene(tmp_path, ramp)).coverage     # per row as many pixels, each row shifted
    assert np.abs(res.coverage.sum(axis=1) - still.sum(axis=1)).max() <= 1
    assert np.flatnonzero(res.coverage[rows[-1]])[0] > np.flatnonzero(still[rows[-1]])[0]
    disp = (tr.X_deformed - tr.X_undeformed)[rows]
    np.testing.assert_allclose(np.nanmax(disp[..., 0], axis=1), v * tau[rows], atol=1e-9)


def test_a_rolling_shutter_renders_truth_at_points_in_each_rows_state(tmp_path):
    """`glsim render --truth` of a rolling shutter with a rotation and a velocity: MapTruth.at of
    the material points of pixels across the rows (their undeformed positions projected into
    camera 0) gives their deformed positions in those rows' states — the maps at those pixels
    (1e-9 mm) — as CompactTruth.at does from a library's header (tests/test_library.py);
    at(step=…) the step's own state."""
    from glsim.scene.camera import project_camera_frame
    from glsim.workflows.sequence import write_sequence

    scene = edge_scene(tmp_path, ramp, exposure={"velocity": [30.0, -10.0, 0.0], "angular_velocity": [0.0, 0.0, 2.0]},
                       sensor={"line_time": 2e-5})
    write_sequence(scene, tmp_path / "r", truth=True, backend="cpu")
    t = load_truth(next((tmp_path / "r").glob("*_0000_truth.npz")))
    maps = t.maps()
    rows, cols = np.nonzero(maps.mask)
    pick = np.linspace(0, len(rows) - 1, 40).astype(int)
    uv, _ = project_camera_frame(maps.X_undeformed[rows[pick], cols[pick]], scene.cameras[0])
    pt = t.at(uv)
    assert pt.valid.all() and len(np.unique(rows[pick])) > 10
    np.testing.assert_allclose(pt.X_deformed, maps.X_deformed[rows[pick], cols[pick]], rtol=0, atol=1e-9)
    assert np.abs(t.at(uv, step=0).X_deformed - pt.X_deformed).max() > 1e-4


BLUR = {"optics": {"focal_length": 25.0, "f_number": 8.0, "focus_distance": 270.0, "pixel_pitch": 0.01},
        "psf": {"kind": "gaussian", "sigma": 0.8}}   # at Z = 300 mm: σ 1.58 px (window 5 + 1), PSF 4 rows


@pytest.mark.parametrize("backend", ["cpu", "gl"])
def test_rolling_shutter_with_blur_renders_each_row_in_its_band(tmp_path, backend, monkeypatch, request):
    """Depth of field and the PSF move light across rows, so a rolling shutter renders row r as
    the band of rows within their reach (glsim.effects.spread: the blur's window 5 + 1 for a
    depth an ulp off, then the PSF's 4) and cuts row r from it. With a still specimen every
    row's state is the same, so the image is the global shutter's bit for bit (the band's pixels
    are the frame's, blurred by the same sums); a band of 8 rows each side, one short of the
    reach 5 + 4, changes rows within that reach of the plate's top and bottom edges."""
    from glsim.compose import exposure as exposuremod
    from glsim.effects import spread

    if backend == "gl":
        request.getfixturevalue("gl_ctx")
    scene = edge_scene(tmp_path, ramp, **BLUR)
    rolling = scene.replace(exposure={"velocity": [0.0, 0.0, 0.0]}, sensor={"line_time": 1e-4})
    assert spread(scene, np.array([Z])) == 10
    still = render(scene, backend, truth=True)
    res = render(rolling, backend, truth=True)
    np.testing.assert_array_equal(res.image, still.image)
    np.testing.assert_array_equal(res.truth.ref_uv, still.truth.ref_uv)
    monkeypatch.setattr(exposuremod, "spread_rows", lambda scene, depths: 8)
    short = render(rolling, backend).image
    differ = np.flatnonzero((short != still.image).any(axis=1))
    edges = np.array([SIZE[1] / 2 - 0.5 - 7.5 * PX_PER_MM, SIZE[1] / 2 - 0.5 + 7.5 * PX_PER_MM])  # rows 11, 36
    assert len(differ) and (np.abs(differ[:, None] - edges).min(axis=1) <= 9).all()


def test_rolling_shutter_with_blur_is_each_rows_blurred_state(tmp_path):
    """With the plate moving, row r of a rolling shutter with depth of field and a PSF is row r
    of the global shutter's image of the plate where it is at τ_r = (r − (H − 1)/2)·L (a load
    step translated by v·τ_r: the states are the same float64 nodes), blurred whole."""
    L, v = 1e-4, np.array([3.0, 0.0, 0.0])     # 0.5 px per row of translation
    scene = edge_scene(tmp_path, ramp, **BLUR)
    tau = row_offsets(SIZE[1], L)
    res = render(scene.replace(exposure={"velocity": v.tolist()}, sensor={"line_time": L}))
    rows = [0, 8, 12, 24, 35, 40, 47]
    shifted = edge_scene(tmp_path, ramp, translations=tuple(tuple(v * tau[r]) for r in rows), **BLUR)
    with Renderer(shifted, "cpu") as r:
        for k, row in enumerate(rows, start=1):
            np.testing.assert_array_equal(res.image[row], r.render(0, k).image[row])


def test_interpolation_between_load_steps(tmp_path):
    """No rigid motion: the state at t_k + τ interpolates linearly between the load steps (at
    k·step_time without solver times) and is held after the last step: the image is the mean of
    static renders of the interpolated translations (np.interp, which holds at the ends)."""
    a, b = (0.4, 0.0, 0.0), (1.0, 0.3, 0.0)
    scene = edge_scene(tmp_path, ramp, translations=(a, b))
    T, S, dt = 1.0, 4, 2.0      # steps at 0, 2, 4 s
    ex = scene.replace(exposure={"time": T, "samples": S, "step_time": dt})
    for step in (1, 2):         # step 2: its last two samples after the last step
        times = step * dt + motion.sample_offsets(T, S)
        states = [tuple(np.interp(t, [0, 2, 4], [0, a[i], b[i]]) for i in range(3)) for t in times]
        with Renderer(edge_scene(tmp_path, ramp, translations=tuple(states)), "cpu") as r:
            expect = sum(r.render(0, k).image.astype(np.float64) for k in range(1, S + 1)) / S
        np.testing.assert_allclose(render(ex, step=step).image, expect, atol=1e-6)


EXPOSURE = {"exposure": {"time": 0.01, "samples": 4, "velocity": [300.0, 100.0, 0.0], "angular_velocity": [0, 0, 5.0]}}
ROLLING = {"exposure": {"time": 0.002, "samples": 2, "velocity": [600.0, 0.0, 0.0]}, "sensor": {"line_time": 5e-5}}


@pytest.mark.usefixtures("gl_ctx")
@pytest.mark.parametrize("sections, mode", [(EXPOSURE, "exact"), (EXPOSURE, "q4"), (EXPOSURE, "fast"),
                                            (ROLLING, "exact"), (ROLLING, "q4"), (ROLLING, "fast")],
                         ids=["exposure-exact", "exposure-q4", "exposure-fast", "rolling-exact", "rolling-q4",
                              "rolling-fast"])
def test_gl_matches_the_oracle(tmp_path, sections, mode):
    """GL and the oracle render the same sub-frames (their node states are made once, in numpy
    float64, for both) and average them alike: off the coverage ties, every pixel within
    glsim.check.oracle_maps.renderer_motion (each sub-frame's still-render bound, averaged, and
    the mean's float32 rounding)."""
    assert_gl_within_its_bound(edge_scene(tmp_path, ramp, **sections), mode)


def assert_gl_within_its_bound(scene, mode, mesh=None, step=0):
    """GL's image of camera 0 at ``step`` in ``mode`` within oracle_maps.renderer_motion of the
    oracle's off its ties (which leave most of the specimen)."""
    with Renderer(scene, "cpu", mesh=mesh) as c, Renderer(scene, "gl", mesh=mesh) as g:
        bound, ties = oracle_maps.renderer_motion(g, c, mode, 0, step)
        d = np.abs(g.render(0, step, mode=mode).image.astype(np.float64) - c.render(0, step, mode=mode).image)
        specimen = bound > 0
    assert specimen.sum() > 300 and (ties & specimen).sum() < 0.1 * specimen.sum()
    assert closed_forms.units(d, bound)[~ties].max() <= 1


@pytest.mark.usefixtures("gl_ctx")
def test_gl_matches_the_oracle_where_no_bound_is_derived(tmp_path):
    """A rolling shutter that oracle_maps.renderer_motion does not cover: with depth of field, each
    row rendered as the band of rows its blur reaches, blurred and cut to the row
    (renderer_dof holds for whole frames; a band's is not derived). The composition alone:
    |GL − oracle| ≤ the largest |GL − oracle| of its sub-frames + 2⁻²⁴ (the mean of differences
    is at most their max; the two roundings of means below 1 add at most 2 · ½ ulp), which
    stays below half a grey level of 8 bit (the requirement the images are made for)."""
    scene = edge_scene(tmp_path, ramp, **{**ROLLING, **BLUR}).replace(render={"mode": "exact"})
    images, frames = {}, {}
    for backend in ("cpu", "gl"):
        with Renderer(scene, backend) as r:
            images[backend] = r.render(0, 0).image
            frames[backend] = [out.image.astype(np.float64) for *_, out in r.sub_frames(0, 0)]
    bound = max(float(np.abs(g - c).max()) for g, c in zip(frames["gl"], frames["cpu"])) + 2 ** -24
    assert float(np.abs(images["gl"] - images["cpu"]).max()) <= bound <= 0.5 / 255


# ---- quadratic elements ----------------------------------------------------------------------------
def q8_moving(velocity, taus):
    """The Q8 paraboloid of glsim.bench.quadratic (96 × 72 px) and the same mesh with load
    steps 1…S translated by velocity·τ_i: step 0's states during the exposure, as nodes to the bit
    (nodes + v·τ, the timeline's own sum)."""
    from glsim.bench import quadratic
    from glsim.scene.mesh import Mesh

    q8 = quadratic.mesh("quad8", 4, 3)
    q8 = Mesh(q8.nodes, q8.quads, q8.node_labels, q8.element_labels, patches=q8.patches)   # step 0 only
    steps = (np.zeros_like(q8.nodes),) + tuple(np.broadcast_to(np.asarray(velocity) * t, q8.nodes.shape).copy()
                                               for t in taus)
    shifted = Mesh(q8.nodes, q8.quads, q8.node_labels, q8.element_labels, steps, patches=q8.patches)
    return quadratic.paraboloid_scene((96, 72)), q8, shifted


@pytest.mark.parametrize("mode", ["exact", "q4", "fast"])
def test_quadratic_rigid_translation_is_the_average_of_shifted_renders(mode):
    """Quadratic elements (Q8) move as linear ones do: the oracle's image is the mean of the
    static renders of the translated patches (exact and q4 map on each state's curved patches,
    fast draws their pieces), and the truth is the mid-exposure state's with the motion range
    of a curved surface moving parallel to the image: uv_end − uv_start = (v_x, v_y)·T·f / Z
    at each pixel's own depth Z (pinhole)."""
    v, T, S = np.array([60.0, -25.0, 0.0]), 0.01, 4
    taus = motion.sample_offsets(T, S)
    scene, q8, shifted = q8_moving(v, taus)
    scene = scene.replace(render={"mode": mode})
    with Renderer(scene, "cpu", mesh=shifted) as r:
        frames = [r.render(0, k).image.astype(np.float64) for k in range(1, S + 1)]
        still = r.render(0, 0, truth=True).truth
    with Renderer(scene.replace(exposure={"time": T, "samples": S, "velocity": v.tolist()}), "cpu", mesh=q8) as r:
        moving = r.render(0, 0, truth=True)
    np.testing.assert_array_equal(moving.image, (sum(frames) / S).astype(np.float32))
    tr, cam = moving.truth, scene.cameras[0]
    assert tr.mask.sum() > 3000
    np.testing.assert_array_equal(tr.element, still.element)
    np.testing.assert_array_equal(tr.X_deformed, still.X_deformed)
    Z = tr.X_deformed[tr.mask][:, 2]
    d = tr.uv_end[tr.mask] - tr.uv_start[tr.mask]
    np.testing.assert_allclose(d, v[:2] * T * np.array([cam.fx, cam.fy]) / Z[:, None], rtol=0, atol=1e-9)


@pytest.mark.parametrize("mode", ["exact", "q4"])
def test_quadratic_motion_gl_matches_the_oracle(gl_ctx, mode):
    """The Q8 paraboloid rotating during the exposure and seen by a rolling shutter, mapped on
    each state's curved patches in the shader: GL within its sub-frames' difference from the
    oracle (assert_gl_within_its_bound; no coverage ties claimed on curved edges: both decide
    them in float64, as in the still renders of test_quadratic). (fast draws the states' pieces,
    linear elements: its outline is the rasterizer's, README "What is not here yet".)"""
    scene, q8, _ = q8_moving((0.0, 0.0, 0.0), ())
    scene = scene.replace(render={"mode": mode}, exposure={"time": 0.004, "samples": 2, "velocity": [40.0, 0.0, 0.0],
                                                           "angular_velocity": [0.0, 0.0, 2.0]},
                          sensor={"line_time": 2e-5})
    assert_gl_within_its_bound(scene, mode, q8)


@pytest.mark.parametrize("table, key", [
    ({"exposure": {"time": -0.1}}, "exposure.time"),
    ({"exposure": {"time": 0.0, "samples": 4}}, "exposure.samples"),
    ({"exposure": {"time": 0.1, "samples": 0}}, "exposure.samples"),
    ({"exposure": {"time": 0.1, "samples": 2.5}}, "exposure.samples"),
    ({"exposure": {"velocity": [1, 2]}}, "exposure.velocity"),
    ({"exposure": {"centre": [0, 0, 0], "velocity": [1, 0, 0]}}, "exposure.centre"),
    ({"exposure": {"velocity": [1, 0, 0], "step_time": 2.0}}, "exposure.step_time"),
    ({"exposure": {"step_time": 0.0}}, "exposure.step_time"),
    ({"sensor": {"line_time": -1e-5}}, "sensor.line_time"),
    ({"sensor": {"line_time": 1e-5}}, "sensor.line_time"),      # no motion to expose it at
])
def test_validation_names_the_key_and_the_fix(table, key):
    data = {"cameras": [{"size": [64, 48], "fx": 500, "fy": 500, "cx": 31.5, "cy": 23.5}],
            "specimen": {"plate": {}, "pose": {"t": [0, 0, 300]}}, **table}
    with pytest.raises(SceneError) as err:
        scene_from_dict(data)
    assert err.value.key == key and " — " in str(err.value)


def test_sub_frames_need_an_exposure(tmp_path):
    with Renderer(edge_scene(tmp_path, ramp), "cpu") as r, pytest.raises(SceneError, match=r"exposure.*\[exposure\]"):
        list(r.sub_frames(0, 0))


def test_unordered_solver_times_are_refused():
    with pytest.raises(SceneError, match="do not increase"):
        motion.step_times((0.0, 2.0, 1.0), 3, 1.0)
    np.testing.assert_array_equal(motion.step_times((None, 1.0), 2, 0.5), [0.0, 0.5])


@pytest.mark.parametrize("backend", ["cpu", "gl"])
def test_absent_or_still_costs_nothing(tmp_path, backend, monkeypatch, request):
    """Without [exposure] the motion code does not run; an instantaneous exposure of a still
    specimen (and a global shutter, line_time 0) gives the same image and truth, bit for bit."""
    if backend == "gl":
        request.getfixturevalue("gl_ctx")
    scene = edge_scene(tmp_path, ramp, translations=((0.3, 0.1, 0.0),))
    plain = render(scene, backend, step=1, truth=True)
    still = render(scene.replace(exposure={}, sensor={"line_time": 0.0}), backend, step=1, truth=True)
    np.testing.assert_array_equal(still.image, plain.image)
    for k in ("element", "xi", "eta", "ref_uv", "X_deformed"):
        np.testing.assert_array_equal(getattr(still.truth, k), getattr(plain.truth, k))
    assert still.truth.uv_start is None and set(still.truth.as_dict()) == set(plain.truth.as_dict())
    monkeypatch.setattr(Renderer, "_moving", lambda *a: pytest.fail("motion code ran without [exposure]"))
    np.testing.assert_array_equal(render(scene, backend, step=1).image, plain.image)


def test_noise_is_added_once_to_the_mean(tmp_path):
    """Temporal and fixed-pattern noise are drawn once on the averaged image, as without motion
    (a still exposure gives the noisy image bit for bit); render_many renders motion scenes too."""
    scene = edge_scene(tmp_path, ramp, translations=((0.3, 0.1, 0.0),)).replace(
        noise={"sigma": 2.0}, sensor={"prnu": 1.0, "dsnu": 2.0})
    plain = render(scene, step=1)
    assert {"noise", "fixed_pattern"} <= set(plain.stages)
    moving = scene.replace(exposure={"time": 0.01, "samples": 3, "velocity": [200.0, 0.0, 0.0]})
    with Renderer(moving.replace(exposure={"velocity": [0.0, 0.0, 0.0]}), "cpu") as r:
        np.testing.assert_array_equal(r.render(0, 1).image, plain.image)
    with Renderer(moving, "cpu") as r:
        one = r.render(0, 1, quantize=True)
        many = list(r.render_many([(0, 1), {"camera": 0, "step": 1, "quantize": True}]))
    assert one.stages == plain.stages and one.image.dtype == np.uint8
    np.testing.assert_array_equal(many[1].image, one.image)
