"""The headless EGL context: one context manager owns its lifetime."""
from __future__ import annotations

import contextlib
import ctypes.util
from typing import Iterator

from glsim.errors import GLUnavailableError

EGL_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1"


def _missing_library() -> str | None:
    for name in ("EGL", "GL"):
        if ctypes.util.find_library(name) is None:
            return f"lib{name}.so"
    return None


def create_context():
    """Make a standalone OpenGL 4.5 core context on EGL (GPU or Mesa llvmpipe).

    Raises GLUnavailableError naming the missing library and the fix.
    """
    import moderngl

    missing = _missing_library()
    if missing:
        raise GLUnavailableError(
            f"no headless OpenGL: {missing} was not found. Install the EGL/Mesa libraries "
            f"(Debian/Ubuntu: apt-get install {EGL_PACKAGES}) or use backend='cpu'.")
    try:
        ctx = moderngl.create_context(standalone=True, backend="egl", require=450)
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
        "egl_device": _egl_device(),
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


def _egl_device() -> str:
    """The EGL devices' extension strings (e.g. EGL_MESA_device_software = llvmpipe)."""
    try:
        egl = ctypes.CDLL(ctypes.util.find_library("EGL"))
        egl.eglGetProcAddress.restype = ctypes.c_void_p
        egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
        query = ctypes.CFUNCTYPE(ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_void_p),
                                 ctypes.POINTER(ctypes.c_int))(
            egl.eglGetProcAddress(b"eglQueryDevicesEXT"))
        string = ctypes.CFUNCTYPE(ctypes.c_char_p, ctypes.c_void_p, ctypes.c_int)(
            egl.eglGetProcAddress(b"eglQueryDeviceStringEXT"))
        devices, count = (ctypes.c_void_p * 8)(), ctypes.c_int()
        if not query(8, devices, ctypes.byref(count)):
            return "unknown"
        names = [(string(devices[i], 0x3055) or b"?").decode() for i in range(count.value)]  # EGL_EXTENSIONS
        return "; ".join(names) or "none"
    except (OSError, AttributeError, TypeError, ValueError):
        return "unknown"
