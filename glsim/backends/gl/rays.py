"""The exact mode's per-camera ray maps (shaders/rays.frag): each pixel sample's undistorted ray,
made once per camera model, supersampling, kind and aperture and kept by the backend's
resources; and the float64 maps' bits on the host, for polishing the truth."""
from __future__ import annotations

import numpy as np

from glsim.backends.gl.context import check_error
from glsim.backends.gl.plan import aperture_literal
from glsim.backends.gl.uniforms import Uniforms


def ray_key(cam, s: int, kind: str, aperture: float = 1.0) -> tuple:
    """A ray map's key: the camera model, supersampling, kind and the samples' aperture (√ fill
    factor; 1 at one sample per pixel, whose samples are the centres)."""
    return "rays", cam.size, cam.intrinsic_values, cam.distortion, s, kind, aperture if s > 1 else 1.0


def ray_map(resources, programs, cam, s: int, kind: str, aperture: float = 1.0):
    """(W·s)×(H·s) undistorted rays: "bits" as float64 pairs (RGBA32UI), "split" as float32 hi +
    lo made in float64, "float" in float32 (RGBA32F); ``aperture`` < 1 (√ of the sensor's fill
    factor) scales the samples' offsets from their pixel centres (at s = 1: the centres)."""
    key = ray_key(cam, s, kind, aperture)
    aperture = key[-1]

    def make():
        ctx, (W, H) = resources.ctx, cam.size
        fp64 = kind != "float"
        defines = {"SS": s, **({"FP64": None} if fp64 else {}),
                   **({"RAY_BITS": None} if kind == "bits" else {"RAY_SPLIT": None} if kind == "split" else {}),
                   **({"APERTURE": aperture_literal(aperture, fp64)} if aperture != 1.0 else {})}
        prog = programs.program("fullscreen.vert", "rays.frag", defines=defines)
        Uniforms({"u_intr": cam.intrinsics, "u_dist": cam.distortion.coeffs,
                  "u_valid_r2": cam.distortion.valid_radius() ** 2}).write(prog)
        out = ctx.texture((W * s, H * s), 4, dtype="u4" if kind == "bits" else "f4")
        out.filter = (ctx.NEAREST, ctx.NEAREST)   # (an integer texture must not filter)
        fbo = ctx.framebuffer(color_attachments=[out])
        fbo.use()
        fbo.viewport = (0, 0, W * s, H * s)
        vao = ctx.vertex_array(prog, [])
        vao.render(ctx.TRIANGLES, vertices=3)
        check_error(ctx, "ray map")
        ctx.detect_framebuffer(0).use()   # (before releasing the framebuffer: see Resources.release)
        vao.release()
        fbo.release()
        return out
    return resources.get(key, make)


def ray_bits(resources, cam):
    """The float64 ray map at one sample per pixel as (H·W, 2) float64 on the host (read once),
    or None if no render made it."""
    key = ray_key(cam, 1, "bits")
    if not resources.has(key):
        return None
    W, H = cam.size
    return resources.get(("host",) + key, lambda: np.frombuffer(resources.get(key, None).read(), np.float64)
                         .reshape(H * W, 2))
