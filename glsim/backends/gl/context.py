"""The headless EGL context: one context manager owns its lifetime."""
from __future__ import annotations

import contextlib
import ctypes.util
from dataclasses import dataclass
from typing import Iterator

from glsim.errors import GLUnavailableError

EGL_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1"


def _missing_library() -> str | None:
    for name in ("EGL", "GL"):
        if ctypes.util.find_library(name) is None:
            return f"lib{name}.so"
    return None


def create_context(device_index: int | None = None):
    """Make a standalone OpenGL 4.5 core context on EGL (GPU or Mesa llvmpipe), on EGL device
    ``device_index`` (:func:`egl_devices`; default: glcontext's choice, which honours
    GLCONTEXT_DEVICE_INDEX).

    Raises GLUnavailableError naming the missing library and the fix.
    """
    import moderngl

    missing = _missing_library()
    if missing:
        raise GLUnavailableError(
            f"no headless OpenGL: {missing} was not found. Install the EGL/Mesa libraries "
            f"(Debian/Ubuntu: apt-get install {EGL_PACKAGES}) or use backend='cpu'.")
    try:
        extra = {} if device_index is None else {"device_index": int(device_index)}
        ctx = moderngl.create_context(standalone=True, backend="egl", require=450, **extra)
    except Exception as exc:  # the driver's own words, wrapped once
        raise GLUnavailableError(
            f"no headless OpenGL 4.5 context could be made through EGL ({exc}). Install the "
            f"EGL/Mesa libraries (apt-get install {EGL_PACKAGES}), check that a GPU driver or "
            f"Mesa llvmpipe is present, or use backend='cpu'.") from exc
    return ctx


@contextlib.contextmanager
def gl_context() -> Iterator:
    """Context manager that creates the EGL context and releases it on exit."""
    ctx = create_context()
    try:
        yield ctx
    finally:
        ctx.release()


def driver_info(ctx) -> dict:
    """moderngl's ``ctx.info`` (vendor, renderer, version, limits), leaving the GL error flag
    clear: it asks the driver for every limit it knows, and a driver that lacks one (Mesa's
    softpipe) answers GL_INVALID_ENUM, which the next :func:`check_error` would blame on a pass."""
    out = ctx.info
    ctx.error   # reading the flag clears it
    return out


def software_renderer(ctx) -> bool:
    """Whether ``ctx`` renders in software (Mesa llvmpipe or softpipe)."""
    renderer = driver_info(ctx)["GL_RENDERER"]
    return "llvmpipe" in renderer or "softpipe" in renderer


def check_error(ctx, where) -> None:
    """Raise if the GL error flag is set (ctx.error reads and clears it); ``where``: what ran,
    a string or what makes it (called only on an error)."""
    err = ctx.error
    if err != "GL_NO_ERROR":
        raise RuntimeError(f"OpenGL error {err} after {where() if callable(where) else where}")


def info(ctx, probe: bool = False) -> dict:
    """What `glsim info` prints: vendor, renderer, version, limits, float64 support and the
    arithmetic the exact and q4 modes get by default, with why (``probe``: also measure the
    float64 rate, :func:`float64_rate`, about 0.3 s on llvmpipe; `glsim info` does)."""
    fp64 = "GL_ARB_gpu_shader_fp64" in ctx.extensions
    gl = driver_info(ctx)
    out = {
        "vendor": gl["GL_VENDOR"],
        "renderer": gl["GL_RENDERER"],
        "version": gl["GL_VERSION"],
        "glsl": _glsl_version(ctx, gl),
        "egl_devices": "; ".join(d.describe() for d in egl_devices()) or "unknown",
        "max_texture_size": gl["GL_MAX_TEXTURE_SIZE"],
        "fp64": fp64,
        "pixel_stage": _pixel_stage_line(ctx),
    }
    if not fp64:
        out["exact_precision"] = ("fp32: the driver has no GL_ARB_gpu_shader_fp64, so precision = 'fp64' "
                                  "runs in float32 (its mapping error: README, accuracy table, fp32 rows)")
        return out
    out["exact_precision"] = "fp64 (precision = 'fp64', the default; the driver has GL_ARB_gpu_shader_fp64)"
    if probe:
        rate = float64_rate(ctx)
        out["fp64_rate"] = f"{rate:.3g} of float32 (measured: the same multiply-adds in both widths)"
        if rate < SLOW_FP64_RATE:
            out["exact_precision"] += (f"; float64 runs at {rate:.2g} of float32 here: precision = 'fp32' "
                                       "renders exact faster, at the fp32 rows' mapping error")
    return out


def _pixel_stage_line(ctx) -> str:
    """`glsim info`'s line on the pixel stage exact and q4 get here (glsim.backends.gl.plan)."""
    from glsim.backends.gl.plan import pixel_stage

    stage = pixel_stage(software_renderer(ctx))
    why = ("a software rasterizer: neither stage is faster throughout" if stage == "fragment" else
           "a GPU: data-centre GPUs shade fragments on a few of their SMs only")
    return f"{stage} (the exact and q4 modes' per-sample passes; {why}; the same bytes either way)"


SLOW_FP64_RATE = 1 / 8   # below this float64 / float32 throughput, glsim info suggests fp32

_RATE_SHADER = """
#version 450
layout(local_size_x = 64) in;
layout(std430, binding = 0) buffer Out { T out_v[]; };
uniform float u_seed;
void main() {
    T a[8], b = T(0.999), c = T(1e-3);
    for (int k = 0; k < 8; ++k) a[k] = T(u_seed) + T(gl_GlobalInvocationID.x * 8u + uint(k)) * T(1e-7);
    for (int i = 0; i < ITERATIONS; ++i)
        for (int k = 0; k < 8; ++k) a[k] = a[k] * b + c;   // 8 independent chains: throughput
    out_v[gl_GlobalInvocationID.x] = a[0] + a[1] + a[2] + a[3] + a[4] + a[5] + a[6] + a[7];
}
"""


def float64_rate(ctx, groups: int = 256, iterations: int = 8192, reps: int = 3) -> float:
    """float64 / float32 arithmetic throughput of this driver: the same multiply-adds (8
    independent chains per invocation) in both widths, timed (best of ``reps``) after a warm-up. About 0.5 on CPUs
    (llvmpipe) and datacentre GPUs, 1/32 to 1/64 on most GeForce and Quadro cards."""
    import time

    seconds = {}
    out = ctx.buffer(reserve=groups * 64 * 8)
    out.bind_to_storage_buffer(0)
    for t in ("float", "double"):
        prog = ctx.compute_shader(_RATE_SHADER.replace("#version 450", f"#version 450\n#define T {t}\n"
                                                       f"#define ITERATIONS {iterations}"))
        prog["u_seed"].value = 1.0
        prog.run(group_x=groups)
        ctx.finish()
        best = float("inf")
        for _ in range(reps):
            t0 = time.perf_counter()
            prog.run(group_x=groups)
            ctx.finish()
            best = min(best, time.perf_counter() - t0)
        seconds[t] = best
        prog.release()
    out.release()
    return seconds["float"] / seconds["double"]


def _glsl_version(ctx, gl: dict) -> str:
    """GL_SHADING_LANGUAGE_VERSION (moderngl's ``ctx.info``, ``gl``, leaves it out): asked of the
    driver through EGL, else derived from the context version (GLSL 4.50 for GL 4.5)."""
    text = gl.get("GL_SHADING_LANGUAGE_VERSION", "")
    if not text:
        try:
            egl = ctypes.CDLL(ctypes.util.find_library("EGL"))
            egl.eglGetProcAddress.restype = ctypes.c_void_p
            egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
            address = egl.eglGetProcAddress(b"glGetString")
            if address:
                value = ctypes.CFUNCTYPE(ctypes.c_char_p, ctypes.c_uint)(address)(0x8B8C)  # GL_SHADING_LANGUAGE_VERSION
                text = (value or b"").decode(errors="replace")
        except (OSError, AttributeError, TypeError, ValueError):
            text = ""
    if not text:
        code = ctx.version_code
        text = f"{code // 100}.{code % 100:02d} (from the GL version)"
    return text


@dataclass(frozen=True)
class EglDevice:
    """One EGL device, as ``eglQueryDevicesEXT`` lists it: ``index`` is moderngl's
    ``device_index`` (EGL order, which is not CUDA's and ignores CUDA_VISIBLE_DEVICES)."""
    index: int
    extensions: str
    cuda: int | None = None   # CUDA device ordinal (EGL_NV_device_cuda), where the driver gives it
    drm: str | None = None    # DRM device file (EGL_EXT_device_drm), where the driver gives it

    @property
    def software(self) -> bool:
        return "EGL_MESA_device_software" in self.extensions.split()

    def describe(self) -> str:
        what = "software (llvmpipe)" if self.software else "GPU"
        extra = [f"CUDA {self.cuda}"] * (self.cuda is not None) + [self.drm] * (self.drm is not None)
        return f"{self.index}: {what}" + (f" ({', '.join(extra)})" if extra else "")


def egl_devices() -> list[EglDevice]:
    """The EGL devices (no context needed); empty where EGL cannot list them."""
    try:
        egl = ctypes.CDLL(ctypes.util.find_library("EGL"))
        egl.eglGetProcAddress.restype = ctypes.c_void_p
        egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]

        def proc(name, restype, *argtypes):
            address = egl.eglGetProcAddress(name)
            return ctypes.CFUNCTYPE(restype, *argtypes)(address) if address else None

        query = proc(b"eglQueryDevicesEXT", ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_void_p),
                     ctypes.POINTER(ctypes.c_int))
        string = proc(b"eglQueryDeviceStringEXT", ctypes.c_char_p, ctypes.c_void_p, ctypes.c_int)
        attrib = proc(b"eglQueryDeviceAttribEXT", ctypes.c_uint, ctypes.c_void_p, ctypes.c_int,
                      ctypes.POINTER(ctypes.c_ssize_t))
        devices, count = (ctypes.c_void_p * 16)(), ctypes.c_int()
        if query is None or string is None or not query(16, devices, ctypes.byref(count)):
            return []
        out = []
        for i in range(count.value):
            ext = (string(devices[i], 0x3055) or b"").decode(errors="replace")     # EGL_EXTENSIONS
            cuda, value = None, ctypes.c_ssize_t()
            if "EGL_NV_device_cuda" in ext and attrib is not None and attrib(devices[i], 0x323A, ctypes.byref(value)):
                cuda = int(value.value)                                               # EGL_CUDA_DEVICE_NV
            drm = string(devices[i], 0x3233) if "EGL_EXT_device_drm" in ext else None   # EGL_DRM_DEVICE_FILE_EXT
            out.append(EglDevice(i, ext, cuda, drm.decode(errors="replace") if drm else None))
        return out
    except (OSError, AttributeError, TypeError, ValueError):
        return []


def gpu_devices(devices: list[EglDevice]) -> list[int]:
    """EGL indices of the GPUs to spread workers over. Where the driver gives CUDA ordinals
    (NVIDIA), the GPUs that have one, in CUDA order, so that worker k lands on CUDA device k
    (the ordinal is the CUDA driver's, which applies CUDA_VISIBLE_DEVICES); else every
    non-software device in EGL order. Empty: no GPU (llvmpipe)."""
    gpus = [d for d in devices if not d.software]
    if any(d.cuda is not None for d in gpus):
        gpus = sorted((d for d in gpus if d.cuda is not None), key=lambda d: d.cuda)
    return [d.index for d in gpus]