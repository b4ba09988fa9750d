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


def check_error(ctx, where: str) -> None:
    """Raise if the GL error flag is set (ctx.error reads and clears it)."""
    err = ctx.error
    if err != "GL_NO_ERROR":
        raise RuntimeError(f"OpenGL error {err} after {where}")


def info(ctx) -> dict:
    """What `glsim info` prints: vendor, renderer, version, limits, float64 support."""
    exts = ctx.extensions
    return {
        "vendor": ctx.info["GL_VENDOR"],
        "renderer": ctx.info["GL_RENDERER"],
        "version": ctx.info["GL_VERSION"],
        "glsl": _glsl_version(ctx),
        "egl_devices": "; ".join(d.describe() for d in egl_devices()) or "unknown",
        "max_texture_size": ctx.info["GL_MAX_TEXTURE_SIZE"],
        "fp64": "GL_ARB_gpu_shader_fp64" in exts,
    }


def _glsl_version(ctx) -> str:
    """GL_SHADING_LANGUAGE_VERSION (moderngl's ctx.info leaves it out): asked of the driver
    through EGL, else derived from the context version (GLSL 4.50 for GL 4.5)."""
    text = ctx.info.get("GL_SHADING_LANGUAGE_VERSION", "")
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