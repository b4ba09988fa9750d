"""What composing a Result from several renders needs of a renderer: its current scene, the FE
mesh and the mesh it draws, the reference, the backend and the mesh's geometry."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from glsim.backends.contract import Curved, Request
from glsim.effects import Effects, prepare as prepare_effects
from glsim.scene import Render, Scene
from glsim.scene.camera import Camera
from glsim.imaging.geometry import MeshGeometry


def curved_patches(mesh, pieces, opts: Render, step: int, tl=None, tau: float = 0.0) -> Curved | None:
    """A quadratic mesh's curved patches as modes exact and q4 map on them (None otherwise) at
    ``step``, or at its state τ s on (``tl``: an exposure's :class:`glsim.effects.motion.Timeline`),
    keyed as :meth:`glsim.imaging.geometry.MeshGeometry.step` keys it."""
    if not mesh.is_quadratic or opts.mode == "fast":
        return None
    if tl is None or tau == 0:
        return Curved(mesh, pieces, step)
    return Curved(mesh, pieces, (step, float(tau)), tl.at(tau, mesh.deformed))


@dataclass(frozen=True, eq=False)
class Drawing:
    """A renderer's specimen for its current scene: ``mesh`` the FE mesh, ``pieces`` a quadratic
    mesh's linear pieces (what mode fast draws; None for linear elements), ``geometry`` the drawn
    mesh as the GL path holds it; ``coeffs``: the renderer's float64 reference interpolants
    per method (made once, :func:`glsim.compose.chain.reference_functions`)."""
    scene: Scene
    mesh: object
    pieces: object
    reference: object
    backend: object
    geometry: MeshGeometry
    coeffs: dict

    @property
    def drawn_mesh(self):
        """The linear mesh drawn: the mesh, or a quadratic mesh's pieces."""
        return self.pieces.mesh if self.mesh.is_quadratic else self.mesh

    def camera_index(self, cam: Camera) -> int:
        """``cam``'s index in the scene (a band camera's or a sample camera's: its camera's, by name)."""
        return self.scene.cameras.index(self.scene.camera(cam.name))

    def curved(self, opts: Render, step: int, tl=None, tau: float = 0.0) -> Curved | None:
        return curved_patches(self.mesh, self.pieces, opts, step, tl, tau)

    def effects(self, cam: Camera, step: int, nodes: np.ndarray, depths: np.ndarray) -> Effects:
        """The scene's effects for ``cam`` at ``step`` with the drawn mesh at ``nodes``
        (:func:`glsim.effects.prepare`)."""
        return prepare_effects(self.scene, nodes, self.drawn_mesh.quads, cam, self.camera_index(cam), step, depths,
                               normals=not self.backend.capabilities.device_geometry)

    def render(self, request: Request):
        return self.backend.render(request)
