"""The one entry point: render a camera at a load step with backend "gl" or "cpu".

    with Renderer(scene) as r:
        res = r.render("cam0", step=1, truth=True)
        res.image, res.truth.ref_uv

Both backends take the same scene and return the same :class:`Result`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from glsim.scene.bilinear import bilinear
from glsim.scene.camera import Camera, to_camera
from glsim.effects import prepare as prepare_effects
from glsim.stages.geometry import MeshGeometry, ViewSpec
from glsim.io.truth import Truth
from glsim.stages.view import View, make_view
from glsim.backends import make_backend
from glsim.stages.reference import make_reference, specimen_mesh
from glsim.scene import Render, Scene


@dataclass(frozen=True, eq=False)
class Result:
    """One rendered image: float32 (H, W) grey levels in [0, 1] of full scale."""
    image: np.ndarray
    camera: Camera
    step: int
    backend: str
    options: Render
    seconds: float
    truth: Truth | None = None
    stages: tuple[str, ...] = ()      # the pipeline stages / GL passes that ran
    saturated: float = 0.0            # fraction of pixels below 0 or above full scale (clipped when written)


class Renderer:
    """Renders one scene with one backend; holds the mesh, reference and backend resources."""

    def __init__(self, scene: Scene, backend: str | None = None, ctx=None, mesh=None, reference=None):
        """``mesh`` / ``reference`` replace the scene's specimen mesh and reference image
        (e.g. a calibration target made in code); ``ctx`` shares a GL context."""
        self.scene = scene
        self.mesh = mesh if mesh is not None else specimen_mesh(scene)
        self.reference = reference if reference is not None else make_reference(scene, self.mesh)
        self.backend_name = backend or scene.render.backend
        self.backend = make_backend(self.backend_name, self.reference, ctx)
        self._geometry: MeshGeometry | None = None

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self.backend.close()

    def view(self, camera: int | str, step: int, deformed: np.ndarray | None = None) -> View:
        """The per-element geometry of ``camera`` at ``step`` (``deformed``: its nodes, if known)
        as a full numpy :class:`View` (O(elements); what the CPU oracle renders), with warnings."""
        cam = self.scene.camera(camera)
        nodes = self.mesh.deformed(step) if deformed is None else deformed
        return make_view(cam, self.reference.camera, self.mesh.nodes, nodes, self.mesh.quads,
                         self.mesh.element_labels)

    @property
    def geometry(self) -> MeshGeometry:
        """The mesh as the GL path holds it: per renderer, per load step (cached), per view O(1)."""
        if self._geometry is None:
            self._geometry = MeshGeometry(self.mesh, self.reference.camera)
        return self._geometry

    def render(self, camera: int | str = 0, step: int = 0, truth: bool = False, **options) -> Result:
        """Render one image. ``options`` override the scene's [render] table (mode, …).

        GL: the view is a :class:`ViewSpec` (the camera's transform; the per-element work runs
        on the GPU from the mesh uploaded once and the step's nodes uploaded once); the CPU
        oracle gets the full numpy :class:`View`."""
        opts = self.scene.replace(render=options).render if options else self.scene.render
        t0 = time.perf_counter()
        cam = self.scene.camera(camera)
        if self.backend_name == "gl":
            view = self.geometry.view(cam, step)
            deformed = view.step_geo.deformed
            depths = view.corner_depths() if self.scene.optics is not None else np.empty(0)
        else:
            deformed = self.mesh.deformed(step)
            view = self.view(camera, step, deformed)
            depths = view.Xd[..., 2]
        fx = prepare_effects(self.scene, deformed, self.mesh.quads, cam, self.scene.cameras.index(cam), step,
                             depths, normals=self.backend_name != "gl")
        image, raster, stages = self.backend.render_view(view, opts, truth, fx)
        seconds = time.perf_counter() - t0
        tr = self._truth(view, deformed, raster) if truth else None
        return Result(image=image, camera=view.camera, step=step, backend=self.backend_name,
                      options=opts, seconds=seconds, truth=tr, stages=tuple(stages),
                      saturated=_saturated(image))

    def _truth(self, view: View | ViewSpec, deformed: np.ndarray, raster: dict) -> Truth:
        W, H = view.camera.size
        elem = raster["element"].reshape(H, W)
        mask = elem >= 0
        xi = np.where(mask, raster["xi"].reshape(H, W), np.nan)
        eta = np.where(mask, raster["eta"].reshape(H, W), np.nan)
        ref = np.where(mask[..., None], raster["ref_uv"].reshape(H, W, 2), np.nan)
        cam1 = self.scene.cameras[0]
        Xu = np.full((H, W, 3), np.nan)
        Xd = np.full((H, W, 3), np.nan)
        q = self.mesh.quads[elem[mask]]
        Xu[mask] = to_camera(bilinear(self.mesh.nodes[q], xi[mask], eta[mask]), cam1)
        Xd[mask] = to_camera(bilinear(deformed[q], xi[mask], eta[mask]), cam1)
        return Truth(mask=mask, element=elem, xi=xi, eta=eta, ref_uv=ref, X_undeformed=Xu, X_deformed=Xd)


def _saturated(image: np.ndarray) -> float:
    """Fraction of pixels below 0 or above full scale (the extremes first: most images have none)."""
    if image.size == 0 or (image.min() >= 0 and image.max() <= 1):
        return 0.0
    return float(np.mean((image < 0) | (image > 1)))


def render(scene: Scene, camera: int | str = 0, step: int = 0, backend: str | None = None,
           truth: bool = False, **options) -> Result:
    """Render one image of ``scene`` (convenience wrapper around :class:`Renderer`)."""
    with Renderer(scene, backend) as r:
        return r.render(camera, step, truth, **options)
