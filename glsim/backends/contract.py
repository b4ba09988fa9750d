"""The backend contract: what :class:`glsim.render.Renderer` asks of a backend, the same for the
float64 CPU oracle and the GL shaders. One request type in (:class:`Request`: a
:class:`~glsim.imaging.geometry.ViewSpec`, the scene's [render] options, the effects, the curved
elements), one result out (:class:`Raster`), and a frozen :class:`Capabilities` the renderer
asks instead of the backend's name. Each backend verifies what it can draw before it allocates
anything (pyvale's renderers verify a request, then render its plan).

Stages are named from one vocabulary, :data:`STAGES`, in the order they run; a backend reports
those it ran (GL runs raster, interpolate and light in one pass, and its blur as passes named
``blur_<scheme>``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from glsim.effects import Effects
from glsim.scene import Render
from glsim.scene.mesh import Mesh
from glsim.scene.quadratic import Pieces
from glsim.imaging.geometry import ViewSpec

STAGES = ("raster", "subsamples", "interpolate", "light", "downsample", "blur", "vignette", "psf", "fixed_pattern",
          "noise")


@dataclass(frozen=True)
class Capabilities:
    """What a backend does itself.

    ``device_geometry``: the per-element work (records, normals, covers) runs on the device from
    the ViewSpec, so the renderer prepares no per-element numpy data for it; ``float64``: exact
    and q4 compute in float64 (GL: ``GL_ARB_gpu_shader_fp64``; precision = "fp64" falls back to
    float32 where False); ``passes``: GL passes that benches time one by one (``pass_times``) and
    full-screen passes (``fullscreen_pass``); ``max_size``: the largest texture and render-target
    side the device takes (px; GL_MAX_TEXTURE_SIZE and GL_MAX_RENDERBUFFER_SIZE), None where there
    is none; ``subpixel_bits``: the rasterizer's sub-pixel precision (GL_SUBPIXEL_BITS: fast mode's
    vertices are snapped to 2^-bits px, glsim.check.closed_forms.tie_px), None where coverage is
    decided in float64."""
    device_geometry: bool
    float64: bool
    passes: bool
    max_size: int | None = None
    subpixel_bits: int | None = None


@dataclass(frozen=True, eq=False)
class Curved:
    """Modes exact and q4 of a quadratic mesh: each sample is mapped on its curved patch. The
    view's elements are ``pieces`` (the mesh's linear pieces); ``mesh`` is the quadratic mesh;
    ``state`` the load step drawn, or a hashable key of a state during its exposure
    (:meth:`glsim.imaging.geometry.MeshGeometry.step`) whose FE nodes are ``nodes``."""
    mesh: Mesh
    pieces: Pieces
    state: int | tuple
    nodes: np.ndarray | None = None

    def deformed(self) -> np.ndarray:
        """The quadratic mesh's nodes in this state (N, 3) world mm."""
        return self.mesh.deformed(self.state) if self.nodes is None else self.nodes


@dataclass(frozen=True)
class Request:
    """One image to render: ``view`` (one camera, one step), ``options`` (the scene's [render]),
    ``truth`` (also the pixel-centre raster), ``effects`` (what the scene asks for), ``curved``,
    ``quantize`` (a bit depth: the image may come back quantised as glsim.io.images.quantize
    does, where the backend can do that exactly), ``polish`` (the raster's (ξ, η) made float64,
    glsim.imaging.truth.polish; False: as the pass gave them, where only its elements are wanted —
    mode fast's Jacobian)."""
    view: ViewSpec
    options: Render
    truth: bool = False
    effects: Effects = field(default_factory=Effects)
    curved: Curved | None = None
    quantize: int | None = None
    polish: bool = True


@dataclass(frozen=True, eq=False)
class Raster:
    """A backend's answer: ``image`` float32 (H, W) in [0, 1] of full scale, or quantised if the
    request asked for it (uint8 / uint16); ``samples``, if the
    request asked for truth, the pixel-centre raster as flat arrays over H·W — ``element`` (−1
    where none; the quadratic patch when curved, else the view's element), ``xi``, ``eta``
    (float64, polished: glsim.imaging.truth.polish), ``ref_uv`` (px); ``stages`` run (STAGES)."""
    image: np.ndarray
    samples: dict | None
    stages: tuple[str, ...]


class Backend(Protocol):
    """``submit`` queues a request and returns a token that ``collect`` turns into its Raster;
    ``render`` is both. A backend that works synchronously (the oracle) does the work in
    ``submit``; GL queues its passes and read-backs there, so that a caller submitting the next
    request before collecting one (``Renderer.render_many``) keeps the GPU busy."""
    name: str
    capabilities: Capabilities

    def render(self, request: Request) -> Raster:
        """Render one request."""

    def submit(self, request: Request) -> object:
        """Start one request."""

    def collect(self, token: object) -> Raster:
        """The Raster of a submitted request (in submission order)."""

    def close(self) -> None:
        """Release what the backend holds (a GL context it made)."""
