"""The camera passes after pixel integration and depth of field, each only when the scene asks
(docs/camera.md): vignetting (shaders/vignette.frag: the float64 gain of
glsim.effects.vignetting as float32), the lens PSF (shaders/psf.frag: two 1-D passes of a
separable kernel, or one 2-D pass with the kernel as a texture; clamp to edge) and the
fixed-pattern noise (shaders/fpn.frag: noise.glsl's generator on the camera's own streams).
Their names are the contract's stages ``vignette``, ``psf``, ``fixed_pattern``."""
from __future__ import annotations

import numpy as np


def psf_passes(kernel) -> tuple[tuple[dict, dict, dict], ...]:
    """(defines, array inputs, uniforms) of each psf.frag pass of a glsim.effects.psf.Kernel."""
    R = kernel.radius
    if kernel.taps is not None:
        taps = tuple(float(t) for t in np.asarray(kernel.taps, np.float32))
        return tuple(({name: None, "RADIUS": R}, {}, {"u_taps": taps}) for name in ("PSF_ROWS", "PSF_COLUMNS"))
    return (({"PSF_2D": None, "RADIUS": R}, {"u_kernel": np.asarray(kernel.kernel, np.float32)}, {}),)


def fpn_uniforms(fx, width: int) -> dict:
    """fpn.frag's uniforms: the camera's seed, the image width, σ of the gain and the offset."""
    return {"u_seed": int(fx.fpn_seed), "u_width": int(width), "u_prnu": fx.sensor.prnu / 100.0,
            "u_dsnu": fx.sensor.dsnu / ((1 << fx.bit_depth) - 1)}
