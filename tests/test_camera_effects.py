"""The camera beyond the paper (issue 31, part A): lens PSF, pixel aperture (fill factor),
vignetting and fixed-pattern noise. The oracle against closed forms (the erf edge of a Gaussian
PSF, the Airy disk's zero and line spread, cos⁴ on a fronto-parallel plate, a sub-pixel edge's
coverage), GL against the oracle within bounds derived from float32 arithmetic, and the tables'
refusals."""
import dataclasses
import math

import numpy as np
import pytest
from scipy import integrate
from scipy.special import j1, ndtr

from glsim.backends.cpu import camera_stages
from glsim.backends.gl.plan import plan
from glsim.effects import Effects
from glsim.effects import noise, psf
from glsim.effects.vignetting import flat_field
from glsim.check import closed_forms
from glsim.errors import SceneError
from glsim.render import Renderer
from glsim.scene import Plate, Psf, Scene, Sensor, scene_from_dict

from _plates import plate_scene

U = 2.0 ** -24            # float32 unit roundoff
# GL's float32 cubic B-spline of a uniform image, relative: 16 products and sums (γ_16), the two
# 4-tap weight sets' sums (8u) and the float32 coefficients' rounding (u)
UNIFORM_INTERP = 25 * U
J1_ZERO = 3.8317059702075125   # the first zero of J1 (Abramowitz & Stegun, table 9.5)
CAMERA_TABLES = ("sensor", "psf", "vignetting")


def edge_image(width: int, k: int, rows: int = 3) -> np.ndarray:
    """0 left of the edge between pixels k and k + 1 (at x = k + ½), 1 from k + 1 on."""
    img = np.zeros((rows, width))
    img[:, k + 1:] = 1.0
    return img


def uniform(scene, backend, ctx, level: float) -> Renderer:
    """A renderer of ``scene`` whose reference image is ``level`` everywhere: every covered
    sample is that grey exactly."""
    with Renderer(scene, "cpu") as r:
        ref = r.reference
    return Renderer(scene, backend, ctx=ctx, reference=dataclasses.replace(ref, image=np.full_like(ref.image, level),
                                                                            dots=None))


def renderer(scene, backend, request, level: float) -> Renderer:
    return uniform(scene, backend, request.getfixturevalue("gl_ctx") if backend == "gl" else None, level)


# ---- the oracle against closed forms -------------------------------------------------------------
@pytest.mark.parametrize("sigma", [0.6, 1.3, 2.5])
def test_gaussian_psf_on_a_straight_edge_is_the_erf(sigma):
    """A step at x = k + ½ (clamp to edge extends both sides) convolved with the Gaussian's cell
    integrals telescopes to Φ((i − k − ½)/σ) exactly, but for the tails the kernel leaves out
    (2·Φ(−(R + ½)/σ), renormalised away) and float64 rounding."""
    k = psf.make_kernel(Psf(kind="gaussian", sigma=sigma))
    R = k.radius
    assert R == math.ceil(4 * sigma) and abs(k.kernel.sum() - 1) < 1e-15
    out = psf.apply(edge_image(40, 19), k)
    i = np.arange(40)
    esf = ndtr((i - 19.5) / sigma)
    assert np.abs(out - esf).max() <= 2 * ndtr(-(R + 0.5) / sigma) + 1e-14
    assert np.ptp(out, axis=0).max() == 0       # every row the same


AIRY = dict(wavelength_nm=550.0, f_number=8.0, pixel_pitch=0.00345)   # first zero 1.556 px


def test_airy_kernel_first_zero_and_normalisation():
    r0 = J1_ZERO / math.pi * AIRY["wavelength_nm"] * 1e-6 * AIRY["f_number"] / AIRY["pixel_pitch"]
    assert r0 == pytest.approx(1.2197 * 550e-6 * 8 / 0.00345, rel=1e-4)
    r = np.linspace(0.5 * r0, 1.5 * r0, 2001)
    v = psf.airy(r, **AIRY)
    assert abs(r[np.argmin(v)] - r0) <= r[1] - r[0]          # the first dark ring
    assert psf.airy(r0, **AIRY) < 1e-30 and np.all(np.diff(psf.airy(np.linspace(0, r0, 50), **AIRY)) < 0)
    k = psf.make_kernel(Psf(kind="airy", **AIRY))
    assert abs(k.kernel.sum() - 1) < 1e-14 and k.taps is None
    for flipped in (k.kernel[::-1], k.kernel[:, ::-1], k.kernel.T):     # symmetric to rounding
        assert np.abs(k.kernel - flipped).max() < 1e-14 * k.kernel.max()


def test_airy_line_spread_of_an_edge_matches_the_integrated_airy_lsf():
    """The edge's line spread (its ESF's differences) against the Airy PSF integrated
    independently (adaptive quadrature) over each pixel column's cell and the kernel's square
    |y| ≤ R + ½, normalised over the square. Tolerance: the kernel's 8-point Gauss–Legendre rule
    is exact to degree 15 per cell, on an integrand with under one ring per cell its error is
    < 1e-9; quad is asked for 1e-11."""
    k = psf.make_kernel(Psf(kind="airy", **AIRY))
    R = k.radius
    W, edge = 2 * R + 5, R + 1
    esf = psf.apply(edge_image(W, edge), k)[1]
    lsf = np.diff(esf)                      # lsf[i − 1] = ESF(i) − ESF(i − 1): column offset i − edge − 1
    scale = math.pi * AIRY["pixel_pitch"] / (AIRY["wavelength_nm"] * 1e-6 * AIRY["f_number"])

    def column(m):       # ∫ over x in the cell m, y in [−R − ½, R + ½] (symmetric in y: twice [0, R + ½])
        def inner(x):
            f = lambda y: (2 * j1(scale * math.hypot(x, y)) / (scale * math.hypot(x, y))) ** 2 \
                if (x or y) else 1.0
            return 2 * integrate.quad(f, 0, R + 0.5, limit=400, epsabs=1e-13, epsrel=1e-11)[0]
        return integrate.quad(inner, m - 0.5, m + 0.5, epsabs=1e-13, epsrel=1e-11)[0]

    cols = np.array([column(m) for m in range(0, R + 1)])
    cols = np.concatenate([cols[:0:-1], cols])     # symmetric in x
    expect = cols / cols.sum()
    got = lsf[edge - R:edge + R + 1]                # ESF(i) − ESF(i−1) for i = edge + 1 − R … edge + 1 + R
    assert np.abs(got - expect).max() < 1e-8, np.abs(got - expect).max()


def wide_plate(size=(64, 48), fx=40.0, **kw) -> Scene:
    """A fronto-parallel plate at 300 mm filling a wide-angle camera's view (corner ray at 41°)."""
    return plate_scene(size=size, fx=fx, plate=Plate(width=800, height=600, nx=4, ny=3, translations=((0, 0, 0),)),
                       **kw)


@pytest.mark.parametrize("backend", ["cpu", pytest.param("gl", marks=pytest.mark.gl)])
def test_cos4_on_a_uniform_fronto_parallel_plate(backend, request):
    """Grey 0.8 everywhere; each pixel (u, v) of a pinhole sees its chief ray at tan²θ =
    ((u − cx)/fx)² + ((v − cy)/fy)²: 0.8·cos⁴θ·(1 + a1 tan²θ + a2 tan⁴θ), to the float32
    rounding of the image (oracle: one rounding; GL: the gain's, the product's: 3 u, and its
    interpolation of the uniform grey, UNIFORM_INTERP)."""
    a1, a2 = 0.05, -0.02
    scene = wide_plate().replace(vignetting={"natural": True, "radial": [a1, a2]})
    with renderer(scene, backend, request, 0.8) as r:
        img = r.render(0, 0).image.astype(np.float64)
        cam = scene.cameras[0]
    H, W = img.shape
    v, u = np.mgrid[0:H, 0:W]
    t2 = ((u - cam.cx) / cam.fx) ** 2 + ((v - cam.cy) / cam.fy) ** 2
    expect = 0.8 / (1 + t2) ** 2 * (1 + a1 * t2 + a2 * t2 ** 2)
    assert expect.min() < 0.4                          # the corners really fall off
    assert np.abs(img - expect).max() <= (3 * U + (UNIFORM_INTERP if backend == "gl" else 0)) * 0.8
    assert np.abs(flat_field(cam, scene.vignetting) * 0.8 - expect).max() < 1e-15


def coverage_of_edge(edge: float, aperture: float, s: int) -> float:
    """The share of a pixel's s samples per row left of ``edge`` (offset from its centre):
    samples at aperture·((i + ½)/s − ½) (none within 1e-3 px of the edge in the cases used)."""
    offs = aperture * ((np.arange(s) + 0.5) / s - 0.5)
    assert np.abs(offs - edge).min() > 1e-3
    return float((offs < edge).mean())


@pytest.mark.parametrize("backend", ["cpu", pytest.param("gl", marks=pytest.mark.gl)])
@pytest.mark.parametrize("fill", [1.0, 0.5, 0.25])
def test_fill_factor_coverage_of_a_sub_pixel_edge(backend, fill, request):
    """A white plate's right edge projects to u = cx + fx·10/300 = 15.5 + 9.6667 px: pixel 25's value
    is the share of its samples left of the edge, s = 8 per axis at offsets √f·((i + ½)/8 − ½):
    that count over 8, to GL's float32 interpolation of the white (UNIFORM_INTERP) and box sum of
    s² samples (s²·u). Its coverage tends to the active area's: clip((0.1667 + √f/2)/√f, 0, 1)."""
    s = 8
    scene = plate_scene(size=(32, 24), fx=290.0, samples_per_pixel=s * s)
    if fill < 1:
        scene = scene.replace(sensor={"fill_factor": fill})
    with renderer(scene, backend, request, 1.0) as r:
        img = r.render(0, 0).image
    edge = 15.5 + 290 * 10 / 300 - 25          # the edge's offset from pixel 25's centre: 0.1667
    want = coverage_of_edge(edge, math.sqrt(fill), s)
    tol = UNIFORM_INTERP + s * s * U
    assert np.abs(img[6:18, 25] - want).max() <= tol, (img[6:18, 25].min(), img[6:18, 25].max(), want)
    assert np.abs(img[6:18, 7:25] - 1).max() <= tol and np.all(img[6:18, 26:] == 0)
    area = min(max((edge + math.sqrt(fill) / 2) / math.sqrt(fill), 0), 1)
    assert abs(want - area) <= 1 / s


def test_full_fill_factor_changes_nothing():
    """fill_factor = 1, or one sample per pixel (at its centre whatever f): the same image bit for
    bit, and no APERTURE define; mode fast takes a fill factor at 1 spp (the preview's drags)."""
    base = plate_scene(size=(64, 48), samples_per_pixel=4)
    with Renderer(base, "cpu") as r0, Renderer(base.replace(sensor={"fill_factor": 1.0}), "cpu") as r1:
        assert r0.render(0, 1).image.tobytes() == r1.render(0, 1).image.tobytes()
        one = base.replace(render={"samples_per_pixel": 1})
        with Renderer(one.replace(sensor={"fill_factor": 0.3}), "cpu") as r2:
            assert r2.render(0, 1).image.tobytes() == r0.render(0, 1, samples_per_pixel=1).image.tobytes()
            assert r2.render(0, 1, mode="fast").stages
    cam = base.cameras[0]
    assert "APERTURE" not in plan(base.render, False, True, Effects(aperture=1.0), cam, cam).define_dict
    assert "APERTURE" not in plan(one.render, False, True, Effects(aperture=0.5), cam, cam).define_dict
    assert "APERTURE" in plan(base.render, False, True, Effects(aperture=0.5), cam, cam).define_dict


def test_fixed_pattern_is_fixed_per_camera_and_has_its_sigma():
    """PRNU: a gain map 1 + prnu·z; DSNU: an offset map dsnu/(2^bits − 1)·z; the same at every
    step of a camera, other for another camera, independent of the temporal noise's streams
    (correlations within 5/√n of 0)."""
    H, W = 200, 300
    flat = np.full((H, W), 0.5)
    seed0, seed1 = noise.fixed_pattern_seed(7, 0), noise.fixed_pattern_seed(7, 1)
    gain = noise.fixed_pattern(flat, 2.0, 0.0, 8, seed0) / 0.5 - 1
    assert abs(gain.std() / 0.02 - 1) < 5 / math.sqrt(2 * H * W) and abs(gain.mean()) < 5 * 0.02 / math.sqrt(H * W)
    off = noise.fixed_pattern(np.zeros((H, W)), 0.0, 3.0, 8, seed0)
    assert abs(off.std() * 255 / 3 - 1) < 5 / math.sqrt(2 * H * W)
    assert abs(np.corrcoef(gain.ravel(), off.ravel())[0, 1]) < 5 / math.sqrt(H * W)
    assert abs(np.corrcoef(gain.ravel(), (noise.fixed_pattern(flat, 2.0, 0, 8, seed1) / 0.5 - 1).ravel())[0, 1]) \
        < 5 / math.sqrt(H * W)
    temporal = noise.standard_normal(np.arange(H * W, dtype=np.uint32), noise.stream_seed(7, 0, 0))
    assert abs(np.corrcoef(gain.ravel(), temporal)[0, 1]) < 5 / math.sqrt(H * W)
    # a uniform plate filling the view, moved at step 1: the same pattern at both steps
    scene = plate_scene(size=(64, 48)).replace(sensor={"prnu": 1.0, "dsnu": 2.0})
    with uniform(scene, "cpu", None, 0.5) as r:
        steps = [r.render(0, k).image for k in (0, 1)]
    assert steps[0].tobytes() == steps[1].tobytes()
    assert abs(steps[0].std() / math.hypot(0.5 * 0.01, 2 / 255) - 1) < 0.1


# ---- GL against the oracle -------------------------------------------------------------------------
GL_CASES = {
    "psf_gaussian": {"psf": {"kind": "gaussian", "sigma": 1.2}},
    "psf_airy": {"psf": {"kind": "airy", **AIRY}},
    "vignetting": {"vignetting": {"natural": True, "radial": [0.3]}},
    "fixed_pattern": {"sensor": {"prnu": 1.0, "dsnu": 2.0}},
    "all": {"psf": {"kind": "gaussian", "sigma": 0.8}, "vignetting": {"natural": True},
            "sensor": {"prnu": 1.0, "dsnu": 2.0}},
}


@pytest.mark.gl
@pytest.mark.parametrize("case", sorted(GL_CASES))
def test_gl_camera_passes_match_the_oracle(case, gl_ctx):
    """GL's image with the effect against the oracle's camera stages applied (float64) to GL's
    own image without it — the same input, so only the passes' arithmetic differs — within
    :func:`glsim.check.closed_forms.camera_passes`; and the passes run are those of the plan."""
    base = plate_scene(size=(96, 72), fx=300.0, samples_per_pixel=4)
    scene = base.replace(**GL_CASES[case])
    with Renderer(base, "gl", ctx=gl_ctx) as r0, Renderer(scene, "gl", ctx=gl_ctx) as r:
        plain = r0.render(0, 1).image
        res = r.render(0, 1)
        cam = scene.cameras[0]
        from glsim.effects import prepare

        fx = prepare(scene, np.zeros((1, 3)), np.zeros((0, 4), np.int64), cam, 0, 1, np.empty(0), normals=False)
    stages: list = []
    want = camera_stages(plain.astype(np.float64), fx, stages)
    assert list(res.stages[-len(stages):]) == stages
    d = np.abs(res.image.astype(np.float64) - want).max()
    bound = closed_forms.camera_passes(fx, plain)
    print(f"{case}: max |GL − oracle| {d:.3g} of full scale, bound {bound:.3g}")
    assert d <= bound and bound <= 0.5 / 255


@pytest.mark.gl
@pytest.mark.parametrize("mode", ["exact", "q4"])
def test_gl_fill_factor_matches_the_oracle(mode, gl_ctx):
    """A uniform plate (grey 0.6) with fill factor 0.3 at 3 × 3 samples: coverage decided alike by
    both (float64 sample points bit for bit; no sample within 0.01 px of the silhouette), so the
    images are equal but for GL's float32 interpolation of the grey (UNIFORM_INTERP) and box sum
    of 9 values (9u), relative to 0.6."""
    scene = plate_scene(size=(160, 120), samples_per_pixel=9, mode=mode).replace(sensor={"fill_factor": 0.3})
    images = []
    for backend, ctx in (("gl", gl_ctx), ("cpu", None)):
        with uniform(scene, backend, ctx, 0.6) as r:
            images.append(r.render(0, 1).image.astype(np.float64))
    assert np.abs(images[0] - images[1]).max() <= (UNIFORM_INTERP + 9 * U) * 0.6
    assert len(np.unique(images[1].astype(np.float32))) >= 3        # partial pixels along the edges


@pytest.mark.gl
def test_gl_aperture_sample_points_are_the_oracle_s(gl_ctx):
    """rays.frag's float64 rays at fill factor 0.45 are pixel_grid's normalized points bit for bit."""
    from glsim.backends.gl.backend import GLBackend
    from glsim.scene.camera import pixel_grid, pixel_to_normalized

    cam = plate_scene(size=(40, 30)).cameras[0]
    k = math.sqrt(0.45)
    b = GLBackend(np.zeros((4, 4), np.float32), ctx=gl_ctx)
    try:
        tex = b._ray_map(cam, 3, "bits", k)
        bits = np.frombuffer(tex.read(), np.uint32).reshape(90, 120, 4)
    finally:
        b.close()
    got = bits.copy().view(np.float64)[..., :2]
    want = pixel_to_normalized(pixel_grid(cam, 9, k), cam.intrinsics)
    assert np.array_equal(got, want)


# ---- absent by default, refusals -----------------------------------------------------------------
def test_absent_tables_add_no_pass_and_no_define():
    scene = plate_scene(size=(64, 48))
    assert all(getattr(scene, t) is None for t in CAMERA_TABLES)
    cam = scene.cameras[0]
    p = plan(scene.render, False, True, Effects(), cam, cam)
    assert not {"psf.frag", "vignette.frag", "fpn.frag"} & {x.shader for x in p.passes}
    assert "APERTURE" not in p.define_dict
    with Renderer(scene, "cpu") as r:
        assert not {"vignette", "psf", "fixed_pattern"} & set(r.render(0, 0).stages)


def test_tables_load_from_a_scene_file():
    d = {"cameras": [{"size": [64, 48], "fx": 100.0, "fy": 100.0, "cx": 31.5, "cy": 23.5}],
         "sensor": {"fill_factor": 0.6, "prnu": 0.5, "dsnu": 1.5},
         "psf": {"kind": "airy", "f_number": 5.6, "pixel_pitch": 0.0055},
         "vignetting": {"natural": True, "radial": [0.1, -0.01], "flat_field": True}}
    s = scene_from_dict(d)
    assert s.sensor == Sensor(0.6, 0.5, 1.5) and s.psf.f_number == 5.6 and s.vignetting.radial == (0.1, -0.01)
    assert scene_from_dict({"cameras": d["cameras"]}).psf is None


@pytest.mark.parametrize("tables, key, words", [
    ({"sensor": {"fill_factor": 0.0}}, "sensor.fill_factor", "(0, 1]"),
    ({"sensor": {"fill_factor": 1.5}}, "sensor.fill_factor", "(0, 1]"),
    ({"sensor": {"prnu": -1.0}}, "sensor.prnu", "[0, 100]"),
    ({"sensor": {"dsnu": -1.0}}, "sensor.dsnu", "≥ 0"),
    ({"psf": {"kind": "gaussian"}}, "psf.sigma", "> 0"),
    ({"psf": {"kind": "gauss", "sigma": 1.0}}, "psf.kind", "not one of"),
    ({"psf": {"kind": "airy", "f_number": 8.0}}, "psf.pixel_pitch", "> 0"),
    ({"psf": {"kind": "gaussian", "sigma": 1.0, "f_number": 8.0}}, "psf.f_number", "not used"),
    ({"vignetting": {"flat_field": True}}, "vignetting.natural", "neither"),
    ({"sensor": {"fill_factor": 0.5}, "render": {"mode": "fast", "samples_per_pixel": 4}}, "sensor.fill_factor",
     "fast"),
])
def test_camera_tables_refuse_with_key_and_fix(tables, key, words):
    d = {"cameras": [{"size": [64, 48], "fx": 100.0, "fy": 100.0, "cx": 31.5, "cy": 23.5}], **tables}
    with pytest.raises(SceneError) as e:
        scene_from_dict(d)
    assert e.value.key == key and words in str(e.value) and " — " in str(e.value)


@pytest.mark.parametrize("shape, where, words", [((14, 15), (7, 7), "odd sides"), ((15, 15), (7, 9), "centroid")])
def test_psf_image_must_be_odd_and_centred(tmp_path, shape, where, words):
    import tifffile

    a = np.zeros(shape, np.float32)
    a[where] = 1.0
    tifffile.imwrite(tmp_path / "psf.tif", a)
    scene = plate_scene(size=(64, 48), base_dir=str(tmp_path)).replace(psf={"kind": "image", "image": "psf.tif"})
    with pytest.raises(SceneError) as e:
        psf.make_kernel(scene.psf, tmp_path)
    assert e.value.key == "psf.image" and words in str(e.value)


def test_psf_image_is_normalised_and_applied(tmp_path):
    """A measured 5 × 3 box PSF: normalised to sum 1, padded square and convolved (flipped)."""
    import tifffile

    a = np.zeros((3, 5), np.float32)
    a[1, 1:5] = [1.0, 4.0, 2.0, 1.0]        # centroid 0.375 px right of the middle: accepted
    tifffile.imwrite(tmp_path / "psf.tif", a)
    k = psf.make_kernel(Psf(kind="image", image="psf.tif"), tmp_path)
    assert k.kernel.shape == (5, 5) and k.kernel.sum() == pytest.approx(1, abs=1e-15)
    img = np.zeros((5, 9))
    img[2, 4] = 1.0
    out = psf.apply(img, k)
    assert np.abs(out[2, 2:7] - np.array([0, 1, 4, 2, 1]) / 8).max() < 1e-16   # a point's image is the PSF
    assert np.abs(np.delete(out, 2, axis=0)).max() == 0


def test_render_writes_the_flat_field_on_request(tmp_path):
    from glsim.io.images import read_image
    from glsim.workflows.sequence import write_sequence

    scene = wide_plate(size=(32, 24)).replace(vignetting={"natural": True, "flat_field": True})
    write_sequence(scene, str(tmp_path / "out"), steps=[0], backend="cpu")
    gain = read_image(tmp_path / "out" / "c_flatfield.tif")
    assert gain.dtype == np.float32 and np.array_equal(gain, flat_field(scene.cameras[0], scene.vignetting)
                                                       .astype(np.float32))
    write_sequence(scene.replace(vignetting={"flat_field": False}), str(tmp_path / "plain"), steps=[0], backend="cpu")
    assert not (tmp_path / "plain" / "c_flatfield.tif").exists()


@pytest.mark.gl
def test_gl_measured_psf_is_not_flipped(gl_ctx, tmp_path):
    """An asymmetric measured PSF (a comet to the right and down): GL's 2-D pass against the
    oracle's convolution of the same GL input, within the 2-D bound of :func:`glsim.check.closed_forms.camera_passes` — a
    kernel applied flipped would miss by the image's contrast."""
    import tifffile
    from glsim.effects import prepare

    a = np.zeros((7, 7), np.float32)
    a[3, 3], a[3, 4], a[4, 5], a[5, 6] = 4.0, 2.0, 1.0, 0.5
    a[3, 2] = 5.0 * 0.3          # keeps the centroid within ½ px of the middle pixel
    tifffile.imwrite(tmp_path / "comet.tif", a)
    base = plate_scene(size=(96, 72), fx=300.0, base_dir=str(tmp_path))
    scene = base.replace(psf={"kind": "image", "image": "comet.tif"})
    with Renderer(base, "gl", ctx=gl_ctx) as r0, Renderer(scene, "gl", ctx=gl_ctx) as r:
        plain, img = r0.render(0, 1).image, r.render(0, 1).image
    fx = prepare(scene, np.zeros((1, 3)), np.zeros((0, 4), np.int64), scene.cameras[0], 0, 1, np.empty(0),
                 normals=False)
    want = camera_stages(plain.astype(np.float64), fx, [])
    flipped = psf.apply(plain, dataclasses.replace(fx.psf, kernel=fx.psf.kernel[::-1, ::-1])).astype(np.float32)
    d = np.abs(img - want).max()
    assert d <= closed_forms.camera_passes(fx, plain) and np.abs(flipped - want).max() > 100 * closed_forms.camera_passes(fx, plain), d


def test_render_refuses_a_bad_measured_psf_before_writing(tmp_path):
    import tifffile
    from glsim.workflows.sequence import write_sequence

    tifffile.imwrite(tmp_path / "psf.tif", np.ones((4, 5), np.float32))
    scene = plate_scene(size=(32, 24), base_dir=str(tmp_path)).replace(psf={"kind": "image", "image": "psf.tif"})
    with pytest.raises(SceneError) as e:
        write_sequence(scene, str(tmp_path / "out"), steps=[0], backend="cpu")
    assert e.value.key == "psf.image" and not (tmp_path / "out" / "scene.json").exists()
