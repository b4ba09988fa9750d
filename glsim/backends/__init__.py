"""Backends: the same scene rendered by the float64 CPU oracle (:mod:`glsim.backends.cpu`) or by
OpenGL shaders (:mod:`glsim.backends.gl`, the only place moderngl is imported), behind one
contract (:mod:`glsim.backends.contract`): ``render(Request) -> Raster`` and their
``capabilities``."""
from __future__ import annotations

from glsim.errors import SceneError
from glsim.scene import BACKENDS


def make_backend(name: str, reference, ctx=None):
    """A backend instance by name ("gl" or "cpu") for a :class:`Reference`; ``ctx`` shares an
    existing GL context."""
    if name == "cpu":
        from glsim.backends.cpu import CPUBackend
        return CPUBackend(reference.image, reference.dots)
    if name == "gl":
        from glsim.backends.gl.backend import GLBackend
        return GLBackend(reference.image, ctx, dots=reference.dots)
    raise SceneError("render.backend", f"{name!r} is not one of {BACKENDS}", "use 'gl' or 'cpu'")
