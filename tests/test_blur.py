"""Depth of field (paper §2.2.2, eqs. 14–19): optics against hand-computed values, the blur
oracle against direct convolutions, the separable approximation's error on a tilted plate,
and the GLSL twin (shaders/dof.glsl, shaders/blur.frag) against numpy."""
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import ndimage

from glsim.effects import dof as blur
from glsim.check import closed_forms

# f = 30 mm, N = 8, c = 4.4 µm (one 4.4 µm pixel), focused at D = 600 mm
F, N, PITCH, D = 30.0, 8.0, 0.0044, 600.0
OPTICS = SimpleNamespace(focal_length=F, f_number=N, focus_distance=D, pixel_pitch=PITCH,
                         coc_px=1.0, kernel="gaussian")


def _speckle(shape, seed=1):
    rng = np.random.default_rng(seed)
    s = ndimage.gaussian_filter(rng.random(shape), 1.5)
    return (s - s.min()) / (s.max() - s.min())


# ---------------------------------------------------------------------------- eqs. 14–19

def test_hyperfocal_and_dof_limits_hand_values():
    # H = f²/(N c) + f = 900 / (8 · 0.0044) + 30 = 900 / 0.0352 + 30 = 25568.1818… + 30
    #   = 281580/11 = 25598.181818… mm
    H = blur.hyperfocal(F, N, PITCH)
    assert H == pytest.approx(281580 / 11, rel=1e-14)
    # D⁻ = D H / (H + D) = 600 · 281580 / (281580 + 6600) = 168948000 / 288180 = 938600/1601
    #    = 586.258588… mm
    # D⁺ = D H / (H − D) = 600 · 281580 / (281580 − 6600) = 168948000 / 274980 = 2815800/4583
    #    = 614.401047… mm
    near, far = blur.dof_limits(D, H)
    assert near == pytest.approx(938600 / 1601, rel=1e-14)
    assert far == pytest.approx(2815800 / 4583, rel=1e-14)


def test_far_limit_is_infinite_at_and_beyond_the_hyperfocal_distance():
    H = 281580 / 11
    # D = 30 m > H: D⁻ = 30000 H / (H + 30000) = 30000 · 281580 / (281580 + 330000)
    #   = 140790000/10193 = 13812.42… mm; D⁺ = ∞ (the paper's text states the condition the
    #   other way round; D H / (H − D) would be negative here)
    near, far = blur.dof_limits(30000.0, H)
    assert near == pytest.approx(140790000 / 10193, rel=1e-14)
    assert far == np.inf
    near, far = blur.dof_limits(H, H)                  # D = H: near = H/2, far = ∞
    assert near == pytest.approx(H / 2, rel=1e-15) and far == np.inf
    nears, fars = blur.dof_limits(np.array([600.0, H, 3e4]), H)   # vectorised
    assert np.isfinite(fars[0]) and np.all(np.isinf(fars[1:]))


def test_coc_hand_values_and_paper_form():
    # CoC = f² |P − D| / (N (P − f) D)
    # P = 500: 900 · 100 / (8 · 470 · 600) = 90000 / 2256000 = 15/376 = 0.0398936… mm
    #          / 0.0044 mm = 9.06673… px
    # P = 700: 900 · 100 / (8 · 670 · 600) = 90000 / 3216000 = 15/536 = 0.0279851… mm
    #          / 0.0044 mm = 6.36024… px  (not symmetric about the focus plane)
    c = blur.coc_mm(np.array([500.0, 700.0, 600.0]), D, F, N)
    np.testing.assert_allclose(c, [15 / 376, 15 / 536, 0.0], rtol=1e-14, atol=0)
    np.testing.assert_allclose(blur.coc_px(np.array([500.0, 700.0]), OPTICS),
                               [15 / 376 / 0.0044, 15 / 536 / 0.0044], rtol=1e-14)
    # the same numbers through eqs. 17–18 as the paper writes them
    P = np.linspace(100.0, 5000.0, 101)
    VD, VP = F * D / (D - F), F * P / (P - F)
    np.testing.assert_allclose(blur.coc_mm(P, D, F, N), np.abs(VD - VP) * F / (N * VD), rtol=1e-11)


def test_rewritten_coc_has_no_float32_cancellation():
    """Why dof.glsl uses f²|P − D|/(N(P − f)D): V_D − V_P in float32 loses digits near focus."""
    P = np.linspace(560.0, 640.0, 801)
    ref = blur.coc_mm(P.astype(np.float32).astype(np.float64), D, F, N)
    f32, D32, N32 = (np.float32(v) for v in (F, D, N))
    P32 = P.astype(np.float32)
    naive = np.abs(f32 * D32 / (D32 - f32) - f32 * P32 / (P32 - f32)) * f32 / (N32 * (f32 * D32 / (D32 - f32)))
    good = f32 * f32 * np.abs(P32 - D32) / (N32 * (P32 - f32) * D32)
    far = np.abs(P - D) >= 1.0
    rel = lambda a: np.max(np.abs(a[far] - ref[far]) / ref[far])  # noqa: E731
    assert rel(good) < 1e-6          # measured 1.2e-7
    assert rel(naive) > 1e-4         # measured 5.1e-4 (at |P − D| ≈ 1 mm)


def test_blur_sigma_in_focus_band_and_background():
    # CoC ≤ c (1 px) holds on [D H/(D + H − f), D (H − 2f)/(H − f − D)] = [586.93, 613.70] mm,
    # a little inside eqs. 14–15's [586.26, 614.40] (those are the D ≫ f approximations)
    H = blur.hyperfocal(F, N, PITCH)
    lo, hi = D * H / (D + H - F), D * (H - 2 * F) / (H - F - D)
    assert lo == pytest.approx(586.9306930693, rel=1e-10) and hi == pytest.approx(613.6974330967, rel=1e-10)
    Z = np.array([lo + 1e-6, hi - 1e-6, lo - 1e-3, hi + 1e-3, 600.0, 0.0, -5.0, 500.0])
    s = blur.blur_sigma(Z, OPTICS)
    assert np.all(s[[0, 1, 4, 5, 6]] == 0.0)
    assert np.all(s[[2, 3]] > 0.5) and np.all(s[[2, 3]] < 0.5 + 1e-4)    # σ jumps to c/2 at the edge
    assert s[7] == pytest.approx(0.5 * 15 / 376 / 0.0044, rel=1e-14)     # σ = CoC/2 = 4.5334 px
    np.testing.assert_array_equal(blur.blur_radius(Z, OPTICS), s)
    loose = SimpleNamespace(**{**vars(OPTICS), "coc_px": 10.0})
    assert blur.blur_sigma(500.0, loose) == 0.0                          # 9.07 px ≤ 10 px: in focus
    with pytest.raises(ValueError, match="focal length"):
        blur.blur_sigma(np.array([600.0, 20.0]), OPTICS)
    as_dict = dict(vars(OPTICS))
    assert blur.blur_sigma(500.0, as_dict) == s[7]


def test_gaussian_weights():
    d = np.arange(-8, 9)
    np.testing.assert_array_equal(blur.gaussian_weights(d, 0.0), (d == 0).astype(float))
    w = blur.gaussian_weights(d, 2.0)                                    # R = 6
    np.testing.assert_allclose(w[np.abs(d) <= 6], np.exp(-d[np.abs(d) <= 6] ** 2 / 8.0), rtol=1e-15)
    assert np.all(w[np.abs(d) > 6] == 0.0)
    assert np.all(blur.gaussian_weights(d, 1.7)[np.abs(d) > 6] == 0) and blur.gaussian_weights(6, 1.7) > 0
    assert list(blur.kernel_radius([0.0, 0.5, 1.7, 2.0], "gaussian")) == [0, 2, 6, 6]
    assert list(blur.kernel_radius([0.0, 0.6, 2.0], "disk")) == [0, 1, 2]


# ---------------------------------------------------------------------------- blur oracle

def test_in_focus_is_the_identity_bit_for_bit():
    img = _speckle((40, 50))
    zero = np.zeros_like(img)
    for fn in (blur.blur_exact, blur.blur_separable, blur.blur_disk):
        out = fn(img, zero)
        assert out.dtype == np.float64 and np.array_equal(out, img)
    # mixed map: the σ = 0 pixels are copied bit for bit next to blurred ones
    s = np.where(np.arange(50)[None, :] < 25, 0.0, 2.5) * np.ones((40, 1))
    for fn in (blur.blur_exact, blur.blur_separable, blur.blur_disk):
        out = fn(img, s)
        assert np.array_equal(out[s == 0], img[s == 0]) and not np.allclose(out[s > 0], img[s > 0])
    # float32 input: same values, returned as float64
    img32 = img.astype(np.float32)
    assert np.array_equal(blur.blur_separable(img32, zero), img32.astype(np.float64))
    with pytest.raises(ValueError):
        blur.blur_exact(img, -zero - 1)


@pytest.mark.parametrize("sigma", [2.0, 1.7, 0.8])
def test_constant_sigma_matches_direct_convolution(sigma):
    img = _speckle((48, 56))
    s = np.full(img.shape, sigma)
    ex, se = blur.blur_exact(img, s), blur.blur_separable(img, s)
    # a truncated Gaussian on a square window is a product: equal everywhere, border included
    # (the clipped window is a product of clipped 1-D windows); measured ≤ 2e-15
    assert np.abs(se - ex).max() < 1e-12
    R = int(np.ceil(3 * sigma))
    k = np.arange(-R, R + 1)
    g = np.exp(-k ** 2 / (2 * sigma ** 2))
    K = np.outer(g, g) / np.outer(g, g).sum()
    inner = (slice(R, -R), slice(R, -R))
    direct = ndimage.correlate(img, K, mode="constant")
    assert np.abs(ex - direct)[inner].max() < 1e-12                      # measured ≤ 3e-15
    # scipy's gaussian_filter with the same radius is the same kernel
    gf = ndimage.gaussian_filter(img, sigma, truncate=3.0, radius=R)
    assert np.abs(ex - gf)[inner].max() < 1e-12
    # …and with its own radius int(3σ + 0.5) (5 instead of 6 for σ = 1.7) it differs by the
    # cut tail: measured 5.7e-4 of full scale for σ = 1.7, 0 for σ = 2 and 0.8
    gf3 = ndimage.gaussian_filter(img, sigma, truncate=3.0)
    assert np.abs(ex - gf3)[inner].max() < 1e-3
    # border: renormalised over the clipped window
    norm = ndimage.correlate(np.ones_like(img), K, mode="constant")
    np.testing.assert_allclose(ex, direct / norm, rtol=0, atol=1e-12)


def test_disk_constant_radius_matches_direct_convolution():
    img = _speckle((48, 56))
    for r in (1.3, 2.5, 3.0):
        R = int(np.ceil(r))
        k = np.arange(-R, R + 1)
        K = np.clip(r + 0.5 - np.hypot(k[None, :], k[:, None]), 0, 1)
        direct = ndimage.correlate(img, K / K.sum(), mode="constant")
        norm = ndimage.correlate(np.ones_like(img), K / K.sum(), mode="constant")
        out = blur.blur_disk(img, np.full(img.shape, r))
        np.testing.assert_allclose(out, direct / norm, rtol=0, atol=1e-12)
        assert np.abs(out - img).max() > 0.05


# ---------------------------------------------------------------------------- tilted plate

def _edge_width(profile):
    """10–90 % rise distance (px) of a monotone 0 → 1 step profile, linear interpolation."""
    x = np.arange(profile.size, dtype=float)
    return np.interp(0.9, profile, x) - np.interp(0.1, profile, x)


def test_tilted_plate_blur_grows_away_from_the_focus_plane():
    # plate tilted about the x axis: depth ramp down the rows 520 → 720 mm (focus at 600 mm),
    # vertical step edge at column 32 (0 | 1)
    Hh, W = 101, 64
    Z = np.linspace(520.0, 720.0, Hh)[:, None] * np.ones((1, W))
    img = (np.arange(W)[None, :] >= 32).astype(float) * np.ones((Hh, 1))
    s = blur.blur_sigma(Z, OPTICS)
    out = blur.blur_exact(img, s)
    width = np.array([_edge_width(row) for row in out])
    z = Z[:, 0]
    sig = s[:, 0]
    sharp = sig == 0
    assert sharp.any() and np.all(width[sharp] == pytest.approx(0.8))   # untouched step: 0.8 px
    near_side, far_side = (~sharp) & (z < D), (~sharp) & (z > D)
    # width grows monotonically with |Z − D| on both sides
    assert np.all(np.diff(width[near_side]) < 0) and np.all(np.diff(width[far_side]) > 0)
    # and is the Gaussian's 10–90 % width 2·1.2816 σ (sampled, truncated at 3σ): within 6 %
    big = sig >= 1.0
    np.testing.assert_allclose(width[big] / sig[big], 2.5631, rtol=0.06)
    # asymmetric about the focus plane: 80 mm in front blurs more than 80 mm behind
    i_near, i_far = np.argmin(np.abs(z - 520)), np.argmin(np.abs(z - 680))
    assert width[i_near] > 1.08 * width[i_far]
    # separable: its vertical pass mixes rows blurred with their neighbours' σ. Measured:
    # 0.011 of full scale at most ≥ 12 rows from the border (at the depth-of-field edge, where
    # σ jumps 0 → 0.54 px), 0.018 in the border rows (one-sided window over a σ gradient); edge
    # widths differ by ≤ 0.14 px ≥ 12 rows from the border, 0.56 px in the first row
    se = blur.blur_separable(img, s)
    err = np.abs(se - out)
    assert err[12:-12].max() < 0.015 and err.max() < 0.025
    dw = np.abs(np.array([_edge_width(row) for row in se]) - width)
    assert dw[12:-12].max() < 0.2 and dw.max() < 0.7


def test_tilted_plate_separable_error():
    """The separable approximation's error where σ varies: a speckle on a plate tilted about a
    diagonal (depth 520 → 720 mm over the image, focus 600 mm, σ 0 … 3.7 px)."""
    Hh, W = 128, 160
    img = _speckle((Hh, W))
    y, x = np.mgrid[0:Hh, 0:W]
    Z = 520.0 + 120.0 * y / (Hh - 1) + 80.0 * x / (W - 1)
    s = blur.blur_sigma(Z, OPTICS)
    ex, se = blur.blur_exact(img, s), blur.blur_separable(img, s)
    err = np.abs(se - ex)
    blurred = s > 0
    # measured, of full scale: max 4.2e-3 (at the image border), 2.4e-3 ≥ 12 px from it; mean
    # 3.5e-4 over all pixels, 4.4e-4 over the blurred ones, where the blur itself changes the
    # image by 4.0e-2 on average (≈ 1 % relative error)
    assert err.max() < 6e-3 and err[12:-12, 12:-12].max() < 3.5e-3
    assert err.mean() < 5e-4 and err[blurred].mean() < 6e-4
    assert np.abs(ex - img)[blurred].mean() > 0.03
    assert np.array_equal(se[~blurred], img[~blurred]) and np.array_equal(ex[~blurred], img[~blurred])
    # σ varying along x only (tilt about the y axis): the vertical pass sees constant σ, exact
    Zx = 520.0 + 200.0 * x / (W - 1)
    sx = blur.blur_sigma(Zx, OPTICS)
    assert np.abs(blur.blur_separable(img, sx) - blur.blur_exact(img, sx)).max() < 1e-12


# ---------------------------------------------------------------------------- GL schemes (numpy mirrors)

def _hard_sigma(shape=(96, 128)):
    """σ of a plate tilted about a diagonal (depth 520 → 720 mm, the in-focus band crossing
    it), a no-surface strip on the left and a hole: σ varies everywhere, jumps 0 → 0.5 px at
    the depth of field's edge and 3.7 px → 0 at the strip and the hole."""
    Hh, W = shape
    y, x = np.mgrid[0:Hh, 0:W]
    Z = 520.0 + 120.0 * y / (Hh - 1) + 80.0 * x / (W - 1)
    Z[:, :8] = 0
    Z[40:56, 60:90] = 0
    return blur.blur_sigma(Z, OPTICS)


def test_hybrid_is_exact_and_gathers_where_sigma_varies_along_the_column():
    img = _speckle((96, 128))
    s = _hard_sigma()
    vary = blur.varying_columns(s)
    # σ constant along x only (tilt about the y axis): no column varies; a ramp down the rows:
    # every blurred pixel (σ differs between its rows)
    ramp_x = blur.blur_sigma(np.broadcast_to(520.0 + np.arange(128.0), (96, 128)), OPTICS)
    assert not blur.varying_columns(ramp_x).any()
    assert vary[s > 0].mean() > 0.95 and not vary[s == 0].any()
    ex = blur.blur_exact(img, s)
    assert np.abs(blur.blur_hybrid(img, s) - ex).max() < 1e-12          # measured 0
    assert np.abs(blur.blur_separable(img, s) - ex).max() > 0.02        # the separable pair: measured 0.024


@pytest.mark.parametrize("tol", [1e-4, 1e-5])
def test_expansion_stays_within_its_bound_of_the_exact_gather(tol):
    """The expansion scheme's rows, moved to each output pixel's σ and window by a third-order
    expansion in 1/σ², err by at most tol of the grey range (Lagrange's bound on every row it
    uses; other rows are summed directly). Measured 1.7e-5 (tol 1e-4) and 1.9e-6 (tol 1e-5),
    with 6.6 % and 44 % of the rows summed directly (rows without σ at the strip and the hole
    included); on a constant σ it is the separable pair."""
    img = _speckle((96, 128))
    s = _hard_sigma()
    ex = blur.blur_exact(img, s)
    stats = {}
    out = blur.blur_expansion(img, s, tol, stats)
    assert np.abs(out - ex).max() <= tol
    assert np.array_equal(out[s == 0], img[s == 0])
    assert 0 < stats["direct_rows"] < (0.1 if tol == 1e-4 else 0.6)
    flat = np.full(img.shape, 2.3)
    stats = {}
    assert np.abs(blur.blur_expansion(img, flat, tol, stats) - blur.blur_exact(img, flat)).max() < 1e-12
    assert stats["direct_rows"] == 0
    # moments: M0 is the row's (centred) weighted sum, as a direct sum says
    M, bound = blur.row_moments(img, s)
    i, j = 70, 100
    k = np.arange(-int(blur.kernel_radius(s[i, j])), int(blur.kernel_radius(s[i, j])) + 1)
    w = np.exp(-k ** 2 / (2 * s[i, j] ** 2))
    f = img[i, j + k] - img[i, j]
    np.testing.assert_allclose(M[:, i, j], [np.sum(w * f * k ** (2 * n)) for n in range(4)], rtol=1e-12)
    assert bound[i, j] == pytest.approx(np.abs(f).max() * np.sum(w * k ** 8.0), rel=1e-12)


# ---------------------------------------------------------------------------- GL twin

def _backend(ctx, dirs=()):
    from glsim.backends.gl.backend import GLBackend
    return GLBackend(np.zeros((4, 4), np.float32), ctx=ctx, shader_dirs=dirs)


def _run(backend, frag, defines, inputs, uniforms, shape):
    """One full-screen fragment pass through the GL backend (the tests' own shaders have no
    compute twin); returns the float32 (H, W) result."""
    tex = backend.fullscreen_pass(frag, defines, inputs, uniforms, shape[::-1], compute=False)
    out = backend.read(tex)
    tex.release()
    return out


def _plate_depth(shape):
    """float32 depth of a plate tilted about a diagonal (520 → 720 mm), a no-surface strip
    (Z = 0) on the left. Depths whose 3σ lies within 1e-4 of an integer (a truncation-radius
    tie) or whose CoC is within 1e-5 of the 1 px threshold (an in-focus tie) — where float32
    and float64 may decide differently — are nudged by 0.01 mm."""
    Hh, W = shape
    y, x = np.mgrid[0:Hh, 0:W]
    Z = (520.0 + 120.0 * y / (Hh - 1) + 80.0 * x / (W - 1)).astype(np.float32)
    Z[:, :6] = 0
    for _ in range(10):
        z64 = Z.astype(np.float64)
        s = blur.blur_sigma(z64, OPTICS)
        c = blur.coc_px(np.where(z64 > 0, z64, 600.0), OPTICS)
        tie = ((s > 0) & (np.abs(3 * s - np.rint(3 * s)) < 1e-4)) | ((z64 > 0) & (np.abs(c - 1.0) < 1e-5))
        if not tie.any():
            return Z
        Z[tie] += np.float32(0.01)
    raise AssertionError("could not remove ties")


@pytest.mark.gl
def test_gl_coc_and_sigma_match_numpy(gl_ctx, tmp_path):
    (tmp_path / "dof_check.frag").write_text(
        '#include "dof.glsl"\nlayout(binding = SAMPLER_DEPTH) uniform sampler2D u_depth;\nout float out_val;\n'
        'void main() {\n    float Z = texelFetch(u_depth, ivec2(gl_FragCoord.xy), 0).r;\n'
        '#ifdef SIGMA\n    out_val = blur_sigma(Z);\n#else\n    out_val = coc_px(max(Z, 40.0));\n#endif\n}\n')
    backend = _backend(gl_ctx, (tmp_path,))
    Z = np.concatenate([np.linspace(100.0, 2000.0, 2048), np.linspace(585.0, 615.0, 2048)])
    Z = Z.astype(np.float32).reshape(64, 64)
    Z[0, :8] = [0, -1, 0, 0, 0, 0, 0, 0]
    uni = blur.shader_uniforms(OPTICS)
    got_c = _run(backend, "dof_check.frag", {}, {"u_depth": Z}, uni, Z.shape).astype(np.float64)
    got_s = _run(backend, "dof_check.frag", {"SIGMA": None}, {"u_depth": Z}, uni, Z.shape).astype(np.float64)
    backend.close()
    z64 = Z.astype(np.float64)
    ref_c = blur.coc_px(np.maximum(z64, 40.0), OPTICS)
    ref_s = blur.blur_sigma(z64, OPTICS)
    # per depth within what float32 allows (glsim.check.closed_forms.coc: the uniforms' rounding,
    # the operations', the cancellation in |Z − D| near focus; Z clamped to ≥ 40 mm as the shader)
    zc = np.maximum(z64, 40.0)
    bound = closed_forms.coc(zc, OPTICS)
    off = zc != D                                   # (in focus CoC = 0: |Z − D| = 0 exactly, in both)
    assert np.all(np.abs(got_c - ref_c)[off] <= bound[off] * ref_c[off]) and np.all(got_c[~off] == 0)
    # σ = CoC/2 beyond the in-focus threshold, 0 within it: but where CoC is within its bound of
    # the threshold, float32 may decide either way
    tie = np.abs(ref_c - OPTICS.coc_px) <= closed_forms.coc(zc, OPTICS) * ref_c
    keep = ~tie & (z64 > F)
    assert np.all(np.abs(got_s - ref_s)[keep] <= 0.5 * bound[keep] * ref_c[keep])
    assert np.all(got_s[z64 <= 0] == 0)


@pytest.mark.gl
def test_gl_blur_matches_numpy_mirror(gl_ctx):
    shape = (72, 96)
    rng = np.random.default_rng(7)
    src32 = rng.random(shape).astype(np.float32)
    Z = _plate_depth(shape)
    z64 = Z.astype(np.float64)
    img = src32.astype(np.float64)
    sigma = blur.blur_sigma(z64, OPTICS)
    radius = blur.blur_radius(z64, OPTICS)
    assert (sigma == 0).sum() > 500 and sigma.max() > 3.5
    backend = _backend(gl_ctx)
    uni = blur.shader_uniforms(OPTICS)
    R = int(blur.kernel_radius(sigma.max()))
    h = backend.fullscreen_pass("blur.frag", {"BLUR_HORIZONTAL": None, "MAX_RADIUS": R},
                                {"u_src": src32, "u_depth": Z}, uni, shape[::-1], compute=False)
    gauss = _run(backend, "blur.frag", {"BLUR_VERTICAL": None, "MAX_RADIUS": R},
                 {"u_src": h, "u_depth": Z}, uni, shape)
    h.release()
    Rd = int(blur.kernel_radius(radius.max(), "disk"))
    disk = _run(backend, "blur.frag", {"BLUR_DISK": None, "MAX_RADIUS": Rd},
                {"u_src": src32, "u_depth": Z}, uni, shape)
    backend.close()

    ref_g = blur.blur_separable(img, sigma)
    ref_d = blur.blur_disk(img, radius)
    # float32 against the float64 mirror, per pixel within what GLSL 4.50 allows the passes
    # (glsim.check.closed_forms.blur)
    M = float(np.abs(src32).max())
    assert np.all(np.abs(gauss - ref_g) <= closed_forms.blur("separable", sigma, M))
    assert np.all(np.abs(disk - ref_d) <= closed_forms.blur("disk", radius, M))
    # in focus and background: the source texel, bit for bit
    keep = sigma == 0
    assert np.array_equal(gauss[keep].view(np.uint32), src32[keep].view(np.uint32))
    assert np.array_equal(disk[keep].view(np.uint32), src32[keep].view(np.uint32))
    assert np.abs(gauss - src32)[~keep].mean() > 0.05


@pytest.mark.gl
@pytest.mark.parametrize("stage", ["fragment", "compute"])
@pytest.mark.parametrize("scheme", ["separable", "hybrid", "gather", "expansion"])
def test_gl_blur_schemes_match_their_numpy_mirrors(gl_ctx, scheme, stage):
    """Each GL scheme's passes (GLBackend.blur_passes) against its float64 mirror, and the exact
    schemes against the oracle's 2-D gather, on a float32 tilted-plate depth (ties removed)
    with a no-surface strip: separable, hybrid and gather per pixel within what float32 allows
    them (glsim.check.closed_forms.blur); expansion within its tolerance of the exact gather
    (EXPANSION_TOL of the grey range, its remainder bound) plus the gather's rounding, and so
    within twice that of its mirror (a row's bound test near its threshold may go either way in
    float32). Either pixel stage (fragment or compute passes)."""
    from types import SimpleNamespace

    shape = (72, 96)
    src32 = np.random.default_rng(7).random(shape).astype(np.float32)
    Z = _plate_depth(shape)
    img, sigma = src32.astype(np.float64), blur.blur_sigma(Z.astype(np.float64), OPTICS)
    backend = _backend(gl_ctx)
    backend.stage = stage
    out = backend.blur_passes(src32, Z, SimpleNamespace(**vars(OPTICS), scheme=scheme), float(sigma.max()),
                              shape[::-1])
    got = backend.read(out)
    backend.close()
    mirror = {"separable": blur.blur_separable, "hybrid": blur.blur_hybrid, "gather": blur.blur_exact,
              "expansion": blur.blur_expansion}[scheme](img, sigma)
    exact = blur.blur_exact(img, sigma)
    M, F = float(np.abs(src32).max()), float(np.ptp(src32))
    rounding = closed_forms.blur("gather" if scheme == "expansion" else scheme, sigma, M)
    if scheme == "expansion":
        assert np.all(np.abs(got - exact) <= blur.EXPANSION_TOL * F + rounding)
        assert np.all(np.abs(got - mirror) <= 2 * blur.EXPANSION_TOL * F + rounding)
    else:
        assert np.all(np.abs(got - mirror) <= rounding)
    if scheme in ("hybrid", "gather"):   # exact schemes: their float64 mirrors are the gather (so GL within rounding of it)
        assert np.abs(mirror - exact).max() <= 1e-12
    keep = sigma == 0            # in focus and background: the source texel, bit for bit
    assert np.array_equal(got[keep].view(np.uint32), src32[keep].view(np.uint32))


@pytest.mark.parametrize("kernel", ["gaussian", "disk"])
def test_gather_linearization_is_the_blur_and_its_size_derivative(kernel):
    """gather_linearization (image Jacobians through the depth of field): C·image is the oracle's
    gather to rounding (a few ulps of grey levels ≤ 1: 1e-14), and ∂out/∂size matches central
    differences of the gather in the size (δ = 1e-6 px: rounding ~1e-16/δ, 1e-8 allowed) on every
    pixel whose window radius is the same at size ± δ; unblurred pixels copy. size_derivative
    matches central differences of blur_sigma in Z (δ = 1e-5 mm) across the focus plane."""
    rng = np.random.default_rng(0)
    image = rng.random((20, 26))
    size = np.where(rng.random((20, 26)) > 0.3, rng.uniform(0.4, 1.6, (20, 26)), 0.0)
    gather = blur.blur_exact if kernel == "gaussian" else blur.blur_disk
    C, d = blur.gather_linearization(image, size, kernel)
    np.testing.assert_allclose(C @ image.ravel(), gather(image, size).ravel(), rtol=0, atol=1e-14)
    h = 1e-6
    moved = [np.where(size > 0, size + sign * h, 0.0) for sign in (1, -1)]
    fd = (gather(image, moved[0]) - gather(image, moved[1])).ravel() / (2 * h)
    same = np.all([blur.kernel_radius(m, kernel) == blur.kernel_radius(size, kernel) for m in moved], axis=0).ravel()
    np.testing.assert_allclose(d[same], fd[same], rtol=0, atol=1e-8)
    assert np.abs(d).max() > 0.1 and not d[size.ravel() == 0].any()
    optics = SimpleNamespace(focal_length=25.0, f_number=8.0, focus_distance=270.0, pixel_pitch=0.01, coc_px=1.0)
    Z = np.linspace(200.0, 340.0, 141)
    fdz = (blur.blur_sigma(Z + 1e-5, optics) - blur.blur_sigma(Z - 1e-5, optics)) / 2e-5
    np.testing.assert_allclose(blur.size_derivative(Z, optics), fdz, rtol=1e-6, atol=1e-9)
