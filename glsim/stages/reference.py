"""Stages "scene → mesh" and "scene → reference": the placed FE mesh and the reference speckle
image with the virtual reference camera that took it (paper §2.1, Fig. 1)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from glsim.scene import mesh as meshmod
from glsim.scene import speckle
from glsim.scene.camera import Camera, look_at, project_camera_frame, to_camera
from glsim.errors import SceneError
from glsim.io.meshfiles import load_mesh
from glsim.scene import Scene

MARGIN_PX = 8  # reference-image border around the specimen's projection


@dataclass(frozen=True, eq=False)
class Reference:
    """The reference image (float32 (H, W) in [0, 1]) and its pinhole camera; for the
    built-in generator also its dots, which ``interpolation = "procedural"`` evaluates
    exactly instead of interpolating the image."""
    image: np.ndarray
    camera: Camera
    dots: speckle.Dots | None = None


def specimen_mesh(scene: Scene) -> meshmod.Mesh:
    """The scene's FE mesh placed in the world (mm), with all its load steps."""
    sp = scene.specimen
    if sp.bulge is not None:
        b = sp.bulge
        m = meshmod.bulge(b.radius, b.thickness, b.w0, b.steps, b.n_core, b.n_ring)
    elif sp.plate is not None:
        p = sp.plate
        m = meshmod.plate(p.width, p.height, p.nx, p.ny)
        steps = [np.broadcast_to(np.asarray(tr, float), m.nodes.shape) for tr in p.translations]
        m = meshmod.with_displacements(m, steps)
    else:
        f = sp.mesh  # path, unit and sources were validated by the scene
        m = load_mesh(
            scene.resolve(f.path), unit=f.unit,
            point_data_steps=list(f.point_data) or None,
            displacement_files=[scene.resolve(x) for x in f.files] or None,
            csv_files=[scene.resolve(x) for x in f.csv] or None, field=f.field or None)
    return meshmod.place_mesh(m, "mm", np.asarray(sp.R, float), np.asarray(sp.t, float))


def _auto_camera(nodes: np.ndarray, toward: np.ndarray, mm_per_px: float,
                 size: tuple[int, int] | None) -> Camera:
    """A pinhole camera looking square onto the node cloud from the side of ``toward``.

    Its distance is ten times the specimen's extent, so the projection of a flat specimen
    is a similarity at ``mm_per_px``. With ``size`` None the image is sized to the specimen
    plus a margin; otherwise the specimen's centroid maps to the image centre.
    """
    c = nodes.mean(axis=0)
    _, _, vt = np.linalg.svd(nodes - c, full_matrices=False)
    normal = vt[2] if np.dot(vt[2], toward - c) > 0 else -vt[2]
    extent = float(np.linalg.norm(nodes - c, axis=1).max()) or 1.0
    dist = 10.0 * extent
    eye = c + dist * normal
    up = -vt[1] if abs(np.dot(vt[1], normal)) < 0.99 else -vt[0]
    R, t = look_at(eye, c, up)
    f = dist / mm_per_px
    probe = Camera(name="reference", size=(1, 1), fx=f, fy=f, cx=0.0, cy=0.0,
                   R=tuple(map(tuple, R)), t=tuple(t))
    uv, _ = project_camera_frame(to_camera(nodes, probe), probe)
    if size is None:
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        W, H = (int(math.ceil(x)) + 2 * MARGIN_PX + 1 for x in hi - lo)
        cx, cy = MARGIN_PX - lo[0], MARGIN_PX - lo[1]
    else:
        W, H = size
        cx, cy = (W - 1) / 2, (H - 1) / 2
    return Camera(name="reference", size=(W, H), fx=f, fy=f, cx=float(cx), cy=float(cy),
                  R=probe.R, t=probe.t)


def camera_scale(cam: Camera, points: np.ndarray) -> float:
    """Mean mm per pixel of ``cam`` at the centroid of ``points`` (world, mm)."""
    z = to_camera(points.mean(axis=0), cam)[2]
    return float(z / math.sqrt(cam.fx * cam.fy))


def make_reference(scene: Scene, mesh: meshmod.Mesh) -> Reference:
    """The reference image and camera: loaded or generated, as the scene's [speckle] says."""
    sp = scene.speckle
    cam1 = scene.cameras[0]
    if sp.image:
        image = speckle.load_reference(scene.resolve(sp.image))
        if sp.camera is not None:
            cam = sp.camera
            if (cam.width, cam.height) != image.shape[::-1]:
                raise SceneError("speckle.camera.size", f"{cam.size} differs from the image's "
                                 f"{image.shape[::-1]}", "give the reference image's size")
        else:  # the scene requires mm_per_px > 0 when there is no camera
            cam = _auto_camera(mesh.nodes, cam1.center, sp.mm_per_px, image.shape[::-1])
        return Reference(image, cam)
    cam_mm_per_px = camera_scale(cam1, mesh.nodes)
    mm_per_px = sp.mm_per_px or cam_mm_per_px / sp.oversample
    cam = sp.camera or _auto_camera(mesh.nodes, cam1.center, mm_per_px, None)
    dot = sp.dot_diameter_px * cam_mm_per_px / mm_per_px
    dots = speckle.draw_dots((cam.height, cam.width), dot, sp.density, seed=sp.seed,
                             edge_px=min(sp.edge_px * cam_mm_per_px / mm_per_px, dot))
    return Reference(speckle.rasterize(dots), cam, dots)
