"""Images quantised as the camera writes them (``Renderer.render(..., quantize=True)``): on the GPU
(shaders/quantize.frag, float64) bit for bit what glsim.io.images.quantize gives, ties included;
the CPU backend and drivers without float64 quantise in numpy."""
import dataclasses

import numpy as np
import pytest

from glsim.io.images import quantize
from glsim.render import Renderer
from glsim.scene import Noise, bulge_scene

BACKENDS = ["cpu", pytest.param("gl", marks=pytest.mark.gl)]


@pytest.mark.gl
@pytest.mark.parametrize("bits", [8, 10, 12, 16])
def test_gpu_quantisation_is_numpys_bit_for_bit(bits, gl_ctx):
    """(k + 0.5) / top rounded to float32 and their float32 neighbours (the products nearest a
    tie), exact ties (0.5: ·top ends in .5), values beyond 0 and 1."""
    from glsim.backends.gl.backend import GLBackend

    b = GLBackend(np.zeros((8, 8), np.float32), ctx=gl_ctx)
    if not b.fp64:
        pytest.skip("the driver has no GL_ARB_gpu_shader_fp64 (the renderer quantises in numpy)")
    top = (1 << bits) - 1
    rng = np.random.default_rng(bits)
    ties = ((rng.integers(0, top, 20000) + 0.5) / top).astype(np.float32)
    values = np.concatenate([np.float32([0, 1, -0.0, 1e-30, 0.5, -0.5, 1.5]), ties, np.nextafter(ties, np.float32(2)),
                             np.nextafter(ties, np.float32(-2)), rng.uniform(-0.2, 1.2, 20000).astype(np.float32)])
    image = np.resize(values, (400, 250)).astype(np.float32)   # (80,007 values, repeated from the start)
    with gl_ctx:
        got = b.quantize_pass(image, bits)
    assert got.dtype == quantize(image, bits).dtype and np.array_equal(got, quantize(image, bits))
    assert ((image * np.float64(top)) % 1 == 0.5).sum() > 0        # exact ties are there (0.5 among them)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("bits", [8, 12])
def test_render_quantised_is_the_float_image_quantised(backend, bits, ctx_for):
    scene = bulge_scene(size=(160, 120), steps=1)
    scene = dataclasses.replace(scene, cameras=tuple(dataclasses.replace(c, bit_depth=bits) for c in scene.cameras),
                                noise=Noise(sigma=0.05 * ((1 << bits) - 1)))   # clips some pixels at both ends
    with Renderer(scene, backend, ctx=ctx_for(backend)) as r:
        f = r.render(1, 1, mode="exact")
        q = r.render(1, 1, mode="exact", quantize=True)
    assert np.array_equal(q.image, quantize(f.image, bits)) and q.image.dtype == (np.uint8 if bits == 8 else np.uint16)
    assert quantize(q.image, bits) is q.image                     # writing it quantises nothing more
    top = (1 << bits) - 1
    ends = ((q.image == 0) | (q.image == top)) & q.coverage
    assert 0 < f.saturated and q.saturated == ends.sum() / q.coverage.sum()
