"""glsim.imaging.interp: numpy kernels against scipy.ndimage and polynomial reproduction."""

import numpy as np
import pytest
from scipy import ndimage

from glsim.imaging import interp
from glsim.errors import SceneError

H, W = 37, 53
SCIPY_ORDER = {"linear": 1, "bspline3": 3, "bspline5": 5}


@pytest.fixture(scope="module")
def image():
    return np.random.default_rng(3).random((H, W))


def _points(rng, n, lo_u, hi_u, lo_v, hi_v):
    return np.stack([rng.uniform(lo_u, hi_u, n), rng.uniform(lo_v, hi_v, n)], axis=-1)


def _border_points(rng, n):
    """Points within the image but less than 2 px from one of its edges (corners included)."""
    uv = _points(rng, n, 0, W - 1, 0, H - 1)
    edge = rng.integers(0, 4, n)
    d = rng.uniform(0, 2, n)
    uv[edge == 0, 0] = d[edge == 0]
    uv[edge == 1, 0] = W - 1 - d[edge == 1]
    uv[edge == 2, 1] = d[edge == 2]
    uv[edge == 3, 1] = H - 1 - d[edge == 3]
    corners = np.array([[0, 0], [W - 1, 0], [0, H - 1], [W - 1, H - 1]], float)
    return np.concatenate([uv, corners])


@pytest.mark.parametrize("method", sorted(SCIPY_ORDER))
@pytest.mark.parametrize("where", ["interior", "border"])
def test_matches_scipy_map_coordinates(image, method, where):
    rng = np.random.default_rng(7)
    uv = _points(rng, 2000, 2, W - 3, 2, H - 3) if where == "interior" else _border_points(rng, 2000)
    coeffs = interp.prepare(image, method, dtype=np.float64)
    got = interp.sample(coeffs, uv, method)
    want = ndimage.map_coordinates(image, [uv[:, 1], uv[:, 0]], order=SCIPY_ORDER[method], mode="mirror",
                                   prefilter=True)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


@pytest.mark.parametrize("method", interp.METHODS)
def test_float32_coefficients_close_to_float64(image, method):
    uv = _points(np.random.default_rng(8), 500, -1, W, -1, H)
    got = interp.sample(interp.prepare(image, method), uv, method)
    want = interp.sample(interp.prepare(image, method, dtype=np.float64), uv, method)
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-6)


@pytest.mark.parametrize("method", interp.METHODS)
def test_interpolates_at_integer_nodes(image, method):
    vv, uu = np.mgrid[0:H, 0:W]
    uv = np.stack([uu, vv], axis=-1).astype(float)
    got = interp.sample(interp.prepare(image, method, dtype=np.float64), uv, method)
    np.testing.assert_allclose(got, image, rtol=0, atol=1e-9)


def test_keys_cubic_reproduces_quadratics():
    vv, uu = np.mgrid[0:H, 0:W].astype(float)

    def quad(u, v):
        return 0.3 + 0.02 * u - 0.01 * v + 1e-3 * u * u - 2e-3 * u * v + 5e-4 * v * v

    coeffs = interp.prepare(quad(uu, vv), "cubic", dtype=np.float64)
    # Taps must stay inside the image, where the data is the polynomial itself.
    uv = _points(np.random.default_rng(9), 3000, 1, W - 2, 1, H - 2)
    got = interp.sample(coeffs, uv, "cubic")
    np.testing.assert_allclose(got, quad(uv[:, 0], uv[:, 1]), rtol=0, atol=1e-9)


@pytest.mark.parametrize("method", interp.METHODS)
def test_weights_partition_of_unity(method):
    t = np.linspace(0, 1, 101)
    w = interp.weights(t, method)
    assert len(w) ** 2 == interp.taps(method)
    np.testing.assert_allclose(np.sum(w, axis=0), 1.0, rtol=0, atol=1e-14)


def test_bspline5_weights_are_the_quintic_basis():
    # Centred quintic B-spline beta5 at the tap distances, from scipy.
    from scipy.interpolate import BSpline

    beta5 = BSpline.basis_element(np.arange(-3, 4), extrapolate=False)
    t = np.linspace(0, 0.999, 50)
    w = interp.weights(t, "bspline5")
    for k, offset in enumerate(range(-2, 4)):
        np.testing.assert_allclose(w[k], np.nan_to_num(beta5(t - offset)), rtol=0, atol=1e-14)


def test_prepare_pads_with_mirror_extension(image):
    coeffs = interp.prepare(image, "linear", dtype=np.float64)
    p = interp.PAD
    assert coeffs.shape == (H + 2 * p, W + 2 * p)
    assert interp.prepare(image, "bspline3").dtype == np.float32
    np.testing.assert_array_equal(coeffs[p:-p, p:-p], image)
    np.testing.assert_array_equal(coeffs[p - 1, p:-p], image[1])  # row -1 mirrors row 1
    np.testing.assert_array_equal(coeffs[p:-p, -p], image[:, -2])  # column W mirrors column W-2


@pytest.mark.parametrize("method", interp.METHODS)
def test_far_outside_is_clamped_and_nan_propagates(image, method):
    coeffs = interp.prepare(image, method)
    uv = np.array([[-1e9, -1e9], [1e9, 1e9], [np.nan, 3.0]])
    got = interp.sample(coeffs, uv, method)
    assert got[0] == pytest.approx(coeffs[0, 0]) and got[1] == pytest.approx(coeffs[-1, -1])
    assert np.isnan(got[2])


def test_sample_keeps_leading_shape(image):
    coeffs = interp.prepare(image, "cubic")
    uv = np.full((3, 4, 2), 5.25)
    assert interp.sample(coeffs, uv, "cubic").shape == (3, 4)


def test_bad_method_and_image_rejected(image):
    with pytest.raises(SceneError, match="use one of linear, cubic, bspline3, bspline5"):
        interp.prepare(image, "lanczos")
    with pytest.raises(SceneError, match="2-D"):
        interp.prepare(np.zeros((4, 4, 3)), "linear")


@pytest.mark.parametrize("method", ["linear", "cubic", "bspline3", "bspline5"])
def test_kernel_sums_behind_the_grey_bounds(method):
    """glsim.check.closed_forms' per-axis Σ|w|, Σ|w'| and Σ|w''| of each interpolant (the
    largest over the texel fraction t; they make gradient_max, hessian and grey) against the
    weights and their derivatives here on 20,000 fractions (w'' by differences of w'): each
    table value is the largest, to its stated digits, and bounds it."""
    from glsim.check import closed_forms

    t = np.linspace(0.0, 1.0, 20001)[:-1]
    w, dw = np.asarray(interp.weights(t, method)), np.asarray(interp.weight_derivatives(t, method))
    d2w = np.gradient(dw, t, axis=1)[:, 1:-1]   # (one-sided at the ends: left out)
    _, s0, s1, s2 = closed_forms._INTERP[method]
    for table, got in ((s0, np.abs(w).sum(0).max()), (s1, np.abs(dw).sum(0).max()), (s2, np.abs(d2w).sum(0).max())):
        assert got <= table * (1 + 1e-3) + 1e-9 and got >= table * 0.99 - 1e-9, (method, table, got)
