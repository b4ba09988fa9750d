"""The mesh as the GPU path holds it: uploaded once per renderer, per load step and per view.

- :class:`MeshGeometry` (one per :class:`~glsim.render.Renderer`): the connectivity, the
  reference camera's view of the undeformed nodes (camera-frame positions and reference-image
  coordinates, per node) and a local origin; the reference check runs once.
- :class:`StepGeometry` (one per load step, shared by every camera): the deformed nodes
  relative to that origin in float64, a bounding sphere, and the shape problems that do not
  depend on the camera (zero area, tiny, folded; relative to the step's median element).
- :class:`ViewSpec` (one per image): the camera and the rigid transform from the local
  frame to the camera frame, ``X_cam = R·(X − origin) + t``, computed in float64 from the
  camera's pose: O(1) work. The backend derives everything per element on the GPU
  (``shaders/view.glsl``); the numpy :class:`~glsim.imaging.view.View` of the same view is
  built only on demand (:meth:`ViewSpec.view`, :meth:`ViewSpec.subset`: truth polishing,
  lighting), never for a plain render.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from glsim.limits import keep
from glsim.scene.camera import Camera, project_camera_frame, to_camera
from glsim.imaging.view import (NEAR_MM, View, check_reference, classify_shapes, extent, make_view,
                               mesh_element_areas)

STEPS_KEPT = 2  # load steps whose deformed nodes stay cached (and uploaded)
VIEWS_KEPT = 8  # views kept per step (StepGeometry.view_of), and views whose uniforms a GL backend keeps


class MeshGeometry:
    """A mesh and the reference camera, in the forms the per-view work starts from."""

    def __init__(self, mesh, ref_camera: Camera):
        self.mesh = mesh
        self.ref_camera = ref_camera
        used = np.unique(mesh.quads)
        self.used_nodes = used
        self.origin = mesh.nodes[used].mean(axis=0)
        self._reference = None
        self._steps: OrderedDict = OrderedDict()
        self.step_builds = 0      # how many StepGeometry were made (tests)

    @property
    def quads(self) -> np.ndarray:
        return self.mesh.quads

    @property
    def labels(self) -> np.ndarray:
        return self.mesh.element_labels

    def reference(self) -> tuple[np.ndarray, np.ndarray]:
        """Per node: undeformed position in the reference camera's frame (N, 3) and its
        reference-image coordinates (N, 2); raises (naming elements) if the reference camera
        cannot see the whole specimen. Computed once."""
        if self._reference is None:
            Xr = to_camera(self.mesh.nodes, self.ref_camera)
            ref_uv, ok = project_camera_frame(Xr, self.ref_camera)
            check_reference(ok[self.mesh.quads], self.labels)
            self._reference = (Xr, ref_uv)
        return self._reference

    def step(self, step: int, state=None, deformed: np.ndarray | None = None) -> "StepGeometry":
        """The :class:`StepGeometry` of load step ``step`` (cached for the last STEPS_KEPT steps);
        with ``state`` (a hashable key, e.g. seconds from the step's time) and its ``deformed``
        nodes, a state during the step's exposure (:mod:`glsim.effects.motion`), cached alike."""
        key = step if state is None else (step, state)
        if key in self._steps:
            self._steps.move_to_end(key)
            return self._steps[key]
        geo = StepGeometry(self, key, self.mesh.deformed(step) if deformed is None else deformed)
        self.step_builds += 1
        self._steps[key] = geo
        while len(self._steps) > STEPS_KEPT:
            self._steps.popitem(last=False)
        return geo

    def view(self, cam: Camera, step: int, state=None, deformed: np.ndarray | None = None) -> "ViewSpec":
        """The :class:`ViewSpec` of ``cam`` at ``step`` (or at its ``state``, see :meth:`step`):
        O(1) once the step is known; the same object while the step stays cached, so what a
        backend derives from a view is made once."""
        return self.step(step, state, deformed).view_of(cam, self.ref_camera)


class StepGeometry:
    """One load step (``index``; (step, τ) for a state during its exposure): deformed nodes
    relative to the mesh's origin (float64, (N, 3)), every node's bounding ``box`` in world mm
    (:func:`~glsim.imaging.view.extent`), a bounding sphere of the used nodes (centred on their
    box, in the local frame), and the camera-independent shape problems."""

    def __init__(self, mesh_geo: MeshGeometry, step: int, deformed: np.ndarray):
        self.mesh_geo = mesh_geo
        self.index = step
        self.deformed = deformed
        self.local = deformed - mesh_geo.origin
        self.box = extent(deformed)
        every = len(mesh_geo.used_nodes) == len(deformed)
        self.used_local = self.local if every else self.local[mesh_geo.used_nodes]
        lo, hi = self.box if every else extent(deformed[mesh_geo.used_nodes])
        self.centre = 0.5 * (lo + hi) - mesh_geo.origin
        self.radius = _farthest(self.used_local, self.centre)
        self._shape = self._problems = None
        self._views: dict[tuple[Camera, Camera], ViewSpec] = {}

    def view_of(self, cam: Camera, ref_camera: Camera) -> "ViewSpec":
        """This step's :class:`ViewSpec` for ``cam`` (kept by the cameras' values, the last
        VIEWS_KEPT: a preview drag makes a new camera every frame)."""
        v = self._views.get((cam, ref_camera))
        if v is None:
            v = keep(self._views, (cam, ref_camera), ViewSpec(cam, ref_camera, self.mesh_geo, self), VIEWS_KEPT)
        return v

    def shape(self) -> dict[str, np.ndarray]:
        """Zero-area, tiny and folded elements (:func:`glsim.imaging.view.classify_shapes`), from
        the local frame (rigid motions leave them unchanged); computed once per step."""
        if self._shape is None:
            problems = classify_shapes(*mesh_element_areas(self.local, self.mesh_geo.quads))
            self._shape = {k: (v if k == "excluded" else np.flatnonzero(v)) for k, v in problems.items()}
        return self._shape

    @property
    def shape_known(self) -> bool:
        """Whether :meth:`shape` was computed."""
        return self._shape is not None

    def problems(self) -> dict[str, np.ndarray]:
        """The shape problems some element has (zero, tiny, folded: sorted indices; read only),
        found once per step."""
        if self._problems is None:
            self._problems = {k: v for k, v in self.shape().items() if k != "excluded" and len(v)}
        return self._problems


def _farthest(points: np.ndarray, centre: np.ndarray) -> float:
    """The largest distance of ``points`` (N, 3) from ``centre``, column by column (numpy's
    arithmetic on rows of 3 loops over 3 at a time)."""
    d2 = sum((points[:, k] - centre[k]) ** 2 for k in range(3))
    return float(np.sqrt(np.maximum.reduce(d2)))


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class ViewSpec:
    """One camera's view of one step as the GPU path takes it: O(1) data.

    ``rotation`` (3×3) and ``translation`` (3,) map the local frame (nodes − origin) to the
    camera frame in float64; ``far`` bounds every corner's depth (from the step's bounding
    sphere) with the same margin as :class:`~glsim.imaging.view.View`.
    """
    camera: Camera
    ref_camera: Camera
    mesh_geo: MeshGeometry
    step_geo: StepGeometry

    rotation: np.ndarray = field(init=False)
    translation: np.ndarray = field(init=False)
    far: float = field(init=False)

    def __post_init__(self):
        # (made here, not as cached properties: a view's uniforms need all three at once)
        R, t = self.camera.rotation, self.camera.translation
        translation = _frozen(R @ self.mesh_geo.origin + t)   # R·origin + t: the local origin in the camera frame
        zc = float(R[2] @ self.step_geo.centre + translation[2])
        object.__setattr__(self, "rotation", _frozen(R))
        object.__setattr__(self, "translation", translation)
        object.__setattr__(self, "far", max(zc + self.step_geo.radius, NEAR_MM) * 1.5)

    def corner_depths(self) -> np.ndarray:
        """Camera-frame Z (mm) of every node the elements use: the same extremes as every
        corner's (O(N), for the depth-of-field radius only)."""
        return self.step_geo.used_local @ self.rotation[2] + self.translation[2]

    def view(self) -> View:
        """The full numpy :class:`View` (O(M); the oracle's input), without warnings."""
        geo = self.mesh_geo
        return make_view(self.camera, self.ref_camera, geo.mesh.nodes, self.step_geo.deformed, geo.quads,
                         geo.labels, warn=False)

    def subset(self, elements: np.ndarray) -> View:
        """The numpy :class:`View` of ``elements`` only, O(len(elements)), for the truth
        polishing of the pixels they cover: corners, projections and reference coordinates;
        no covers (``cover`` zero, ``bbox`` empty)."""
        geo = self.mesh_geo
        q = geo.quads[elements]
        Xd = to_camera(self.step_geo.deformed[q], self.camera)
        uv, ok = project_camera_frame(Xd, self.camera)
        Xr, ref_uv = geo.reference()
        m = len(q)
        return View(camera=self.camera, ref_camera=self.ref_camera, Xd=Xd, Xr=Xr[q], uv=uv, ref_uv=ref_uv[q],
                    projectable=ok.all(axis=1), cover=np.zeros((m, 4, 2)),
                    bbox=np.tile(np.array([0, 0, -1, -1], np.int64), (m, 1)), far=self.far)
