"""glsim.scene.speckle: generated pattern statistics, argument checks, reference-image loading."""

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

from glsim.io import images
from glsim.scene import speckle
from glsim.errors import SceneError

SHAPE = (400, 400)


@pytest.fixture(scope="module")
def patterns():
    return {d: speckle.generate(SHAPE, d, seed=11) for d in (3, 4, 6, 8)}


def test_same_seed_identical_different_seed_differs():
    a = speckle.generate((120, 90), 4, seed=5)
    b = speckle.generate((120, 90), 4, seed=5)
    c = speckle.generate((120, 90), 4, seed=6)
    assert a.dtype == np.float32 and a.shape == (120, 90)
    np.testing.assert_array_equal(a, b)
    assert np.mean(a != c) > 0.2


def test_grey_levels_span_black_to_white(patterns):
    img = patterns[4]
    assert img.min() == pytest.approx(0.1, abs=1e-6) and img.max() == pytest.approx(0.9, abs=1e-6)
    img = speckle.generate((100, 100), 4, seed=1, black=0.0, white=1.0)
    assert img.min() == 0.0 and img.max() == 1.0


@pytest.mark.parametrize("d", [4, 6, 8])
def test_dot_diameter_recovered(patterns, d):
    stats = speckle.speckle_stats(patterns[d])
    assert stats["dot_diameter_px"] == pytest.approx(d, rel=0.15)


@pytest.mark.parametrize("d", [4, 6, 8])
def test_sparse_speckles_have_the_dot_diameter(d):
    # Where dots rarely overlap the connected components are the dots themselves.
    stats = speckle.speckle_stats(speckle.generate(SHAPE, d, density=0.15, seed=12))
    assert stats["speckle_diameter_px"] == pytest.approx(d, rel=0.15)


@pytest.mark.parametrize("d", [3, 4, 6, 8])
def test_speckles_at_least_3px_and_good_contrast(patterns, d):
    stats = speckle.speckle_stats(patterns[d])
    assert stats["speckle_diameter_px"] >= 3
    assert stats["n_speckles"] > 50
    assert stats["grey_std"] > 0.25 * (0.9 - 0.1)
    assert stats["grey_std"] > 0.25
    assert 0 < stats["autocorr_radius_px"] < d


@pytest.mark.parametrize("density", [0.3, 0.5, 0.7])
def test_covered_fraction_matches_density(density):
    stats = speckle.speckle_stats(speckle.generate(SHAPE, 5, density=density, seed=13))
    assert stats["covered_fraction"] == pytest.approx(density, abs=0.05)
    assert stats["dot_diameter_px"] == pytest.approx(5, rel=0.15)


def test_hard_edge_is_binary():
    img = speckle.generate((80, 80), 4, seed=2, edge_px=0)
    assert set(np.unique(img)) <= {np.float32(0.1), np.float32(0.9)}


@pytest.mark.parametrize("kwargs, key, text", [
    ({"dot_diameter_px": 1.5}, "speckle.dot_diameter_px", "at least 2 px"),
    ({"dot_diameter_px": "big"}, "speckle.dot_diameter_px", "expected a number"),
    ({"density": 0.0}, "speckle.density", "strictly between 0 and 1"),
    ({"density": 1.2}, "speckle.density", "strictly between 0 and 1"),
    ({"edge_px": -1}, "speckle.edge_px", "edge width"),
    ({"diameter_spread": 1.0}, "speckle.diameter_spread", "[0, 1)"),
    ({"black": 0.9, "white": 0.2}, "speckle.black", "black < white"),
    ({"white": 1.5}, "speckle.white", "[0, 1]"),
    ({"seed": 1.5}, "speckle.seed", "integer seed"),
    ({"seed": -1}, "speckle.seed", "integer seed"),
    ({"shape": (0, 10)}, "speckle.shape", "image size in px"),
])
def test_bad_arguments_rejected(kwargs, key, text):
    args = {"shape": (50, 50), "dot_diameter_px": 4, **kwargs}
    with pytest.raises(SceneError) as info:
        speckle.generate(**args)
    assert info.value.key == key
    assert key in str(info.value) and text in str(info.value)


@pytest.fixture(scope="module")
def grey():
    return speckle.generate((40, 60), 4, seed=3, black=0.0, white=1.0).astype(np.float64)


def test_load_8bit_tiff_and_png(tmp_path, grey):
    u8 = np.round(grey * 255).astype(np.uint8)
    for name in ("ref.tif", "ref.png"):
        path = tmp_path / name
        (tifffile.imwrite if name.endswith(".tif") else iio.imwrite)(path, u8)
        img = images.load_reference(path)
        assert img.dtype == np.float32 and img.shape == (40, 60)
        np.testing.assert_array_equal(np.round(img * 255).astype(np.uint8), u8)


def test_load_16bit_tiff_and_png(tmp_path, grey):
    u16 = np.round(grey * 65535).astype(np.uint16)
    for name in ("ref16.tiff", "ref16.png"):
        path = tmp_path / name
        (tifffile.imwrite if name.endswith(".tiff") else iio.imwrite)(path, u16)
        img = images.load_reference(str(path))
        np.testing.assert_allclose(img, u16 / 65535.0, rtol=0, atol=1e-7)


def test_load_float_tiff(tmp_path, grey):
    path = tmp_path / "ref_f.tif"
    tifffile.imwrite(path, grey.astype(np.float32))
    np.testing.assert_array_equal(images.load_reference(path), grey.astype(np.float32))


def test_rgb_rejected(tmp_path, grey):
    path = tmp_path / "rgb.png"
    iio.imwrite(path, np.repeat((grey[..., None] * 255).astype(np.uint8), 3, axis=-1))
    with pytest.raises(SceneError, match="colour image.*greyscale") as info:
        images.load_reference(path)
    assert str(path) in str(info.value) and info.value.key == "speckle.image"


def test_out_of_range_float_rejected(tmp_path, grey):
    path = tmp_path / "hdr.tif"
    tifffile.imwrite(path, (grey * 2).astype(np.float32))
    with pytest.raises(SceneError, match=r"outside \[0, 1\].*scale the image"):
        images.load_reference(path)


def test_missing_and_unreadable_files_rejected(tmp_path):
    missing = tmp_path / "nope.tif"
    with pytest.raises(SceneError, match="file not found") as info:
        images.load_reference(missing, key="cameras[0].reference")
    assert str(missing) in str(info.value) and info.value.key == "cameras[0].reference"
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not an image")
    with pytest.raises(SceneError, match="cannot read image") as info:
        images.load_reference(junk)
    assert str(junk) in str(info.value)


def test_stats_of_flat_image_are_nan_not_errors():
    stats = speckle.speckle_stats(np.full((32, 32), 0.5))
    assert stats["n_speckles"] == 0 and np.isnan(stats["dot_diameter_px"])
    assert stats["grey_std"] == 0.0


def test_dot_diameter_error_names_one_limit():
    """Issue 29: the message said "≥ 2 px" and "at least 3 camera pixels"."""
    from glsim.scene import Speckle

    for make in (lambda: Speckle(dot_diameter_px=1.5), lambda: speckle.draw_dots((32, 32), 1.5)):
        with pytest.raises(SceneError, match="speckle.dot_diameter_px") as e:
            make()
        assert "2 px" in str(e.value) and "3" not in str(e.value).replace("1.5", "")


def test_gradient_is_the_derivative_of_evaluate():
    """speckle.gradient (image Jacobians with a procedural reference) against central
    differences of evaluate (δ = 1e-6 px: rounding ~1e-16/δ of grey ≤ 1, truncation ≤ the
    smoothstep's third derivative 12/edge³ · δ²/6; 1e-8 allowed) at 5,000 random points over
    overlapping dots with 2 px edges; non-zero on their edges, zero with a hard edge."""
    dots = speckle.draw_dots((60, 80), 6.0, 0.5, seed=3, edge_px=2.0)
    uv = np.random.default_rng(0).uniform(5, 55, (5000, 2))
    g = speckle.gradient(dots, uv)
    h = 1e-6
    fd = np.stack([(speckle.evaluate(dots, uv + e) - speckle.evaluate(dots, uv - e)) / (2 * h)
                   for e in ([h, 0.0], [0.0, h])], -1)
    np.testing.assert_allclose(g, fd, rtol=0, atol=1e-8)
    assert (np.abs(g) > 0.01).any(axis=1).mean() > 0.2
    hard = speckle.draw_dots((60, 80), 6.0, 0.5, seed=3, edge_px=0.0)
    assert not speckle.gradient(hard, uv).any()


@pytest.mark.parametrize("reach", [6.999002704514054, 1.0 + 2.0 ** -30, 0.3, 7.0])
def test_dot_grid_cell_is_a_float32_at_least_the_reach(reach):
    """The cell is the float the shaders receive (procedural.glsl's cell corners k·cell are then
    the host's, where each dot's offset from its corner is made: a float64 cell put them up to
    k·2^-24·cell apart, 6e-6 of full scale in grey on the plate) and at least the dots' reach,
    max(reach, 1) rounded up, so that a point's dots stay in its 3 × 3 cells; the values of
    speckle.evaluate do not depend on it."""
    radius = reach - 0.5
    dots = speckle.Dots(np.array([[3.0, 4.0], [40.0, 9.5]]), np.array([radius, radius / 2]), 1.0, 0.1, 0.9, (60, 60))
    cell = speckle.dot_grid(dots).cell
    assert cell == float(np.float32(cell)) and cell >= max(dots.reach, 1.0)
    assert cell == max(dots.reach, 1.0) or float(np.nextafter(np.float32(cell), np.float32(0))) < max(dots.reach, 1.0)
