"""Stages "scene → mesh" and "scene → reference": the placed FE mesh and the reference speckle
image with the virtual reference camera that took it (paper §2.1, Fig. 1)."""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from glsim.scene import mesh as meshmod
from glsim.scene import speckle
from glsim.scene.camera import Camera, look_at, project_camera_frame, to_camera
from glsim.errors import RenderWarning, SceneError
from glsim.io.fe import load_mesh, load_series
from glsim.io.series import is_time_series
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
        if is_time_series(scene.resolve(f.path)):
            m = load_series(scene.resolve(f.path), unit=f.unit, displacement=f.displacement,
                            times=f.times, steps=f.steps)
        elif f.displacement or f.times or f.steps:
            raise SceneError("specimen.mesh.path", f"{f.path} holds no time series (an XDMF file without "
                             "a temporal collection)", "use point_data, files or csv with single-state files")
        else:
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
        check_coverage(mesh, cam, sp.mm_per_px if sp.camera is None else 0.0)
        return Reference(image, cam)
    cam_mm_per_px = camera_scale(cam1, mesh.nodes)
    mm_per_px = sp.mm_per_px or cam_mm_per_px / sp.oversample
    cam = sp.camera or _auto_camera(mesh.nodes, cam1.center, mm_per_px, None)
    if sp.camera is not None:
        check_coverage(mesh, cam)
    dot = sp.dot_diameter_px * cam_mm_per_px / mm_per_px
    dots = speckle.draw_dots((cam.height, cam.width), dot, sp.density, seed=sp.seed,
                             edge_px=min(sp.edge_px * cam_mm_per_px / mm_per_px, dot))
    return Reference(speckle.rasterize(dots), cam, dots)


def coverage(mesh: meshmod.Mesh, cam: Camera, n: int = 4) -> float:
    """The fraction of the undeformed specimen's area that ``cam`` (the reference camera) sees
    inside its image, from n×n points per element weighted by element area."""
    q = mesh.nodes[mesh.quads]                                        # (M, 4, 3)
    g = (np.arange(n) + 0.5) / n * 2 - 1
    xi, eta = (a.ravel() for a in np.meshgrid(g, g))
    w = np.stack([(1 - xi) * (1 - eta), (1 + xi) * (1 - eta), (1 + xi) * (1 + eta), (1 - xi) * (1 + eta)], 1) / 4
    pts = np.einsum("sk,mkd->msd", w, q)                              # (M, n², 3)
    area = 0.5 * (np.linalg.norm(np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]), axis=1)
                  + np.linalg.norm(np.cross(q[:, 2] - q[:, 0], q[:, 3] - q[:, 0]), axis=1))
    uv, ok = project_camera_frame(to_camera(pts, cam), cam)
    W, H = cam.size
    inside = ok & (uv[..., 0] >= -0.5) & (uv[..., 0] <= W - 0.5) & (uv[..., 1] >= -0.5) & (uv[..., 1] <= H - 0.5)
    total = float(area.sum()) * n * n
    return float((inside * area[:, None]).sum() / total) if total > 0 else 1.0


def check_coverage(mesh: meshmod.Mesh, cam: Camera, mm_per_px: float = 0.0, tolerance: float = 1e-3) -> float:
    """Warn (RenderWarning, with the numbers) when the reference image does not cover the
    specimen: the specimen outside it renders as background and is masked in the truth.
    ``mm_per_px``: the image scale, for the message, when the reference camera is automatic
    (the image is then centred on the specimen). Returns the covered fraction."""
    frac = coverage(mesh, cam)
    if frac >= 1.0 - tolerance:
        return frac
    uv, ok = project_camera_frame(to_camera(mesh.nodes, cam), cam)
    W, H = cam.size
    lo, hi = uv[ok].min(axis=0), uv[ok].max(axis=0)
    where = f"the specimen's reference view spans u {lo[0]:.0f}…{hi[0]:.0f}, v {lo[1]:.0f}…{hi[1]:.0f} px"
    key = "speckle.image"
    if mm_per_px > 0:
        need = [math.ceil(2 * max(abs(lo[i] - c), abs(hi[i] - c))) + 1
                for i, c in ((0, cam.cx), (1, cam.cy))]
        scale = mm_per_px * max(need[0] / W, need[1] / H)
        where = (f"the image is {W}×{H} px = {W * mm_per_px:.4g}×{H * mm_per_px:.4g} mm at {mm_per_px:g} mm/px, "
                 f"centred on the specimen, whose reference view spans {(hi[0] - lo[0]) * mm_per_px:.4g}"
                 f"×{(hi[1] - lo[1]) * mm_per_px:.4g} mm")
        fix = (f"give an image of at least {need[0]}×{need[1]} px at {mm_per_px:g} mm/px, or set "
               f"speckle.mm_per_px ≥ {scale:.4g} to stretch this one over the specimen")
    else:
        key = "speckle.camera"
        where += f" of the {W}×{H} px reference image"
        fix = "give a larger image, or a speckle.camera that sees the whole specimen"
    warnings.warn(f"{key}: the reference image covers only {100 * frac:.3g} % of the specimen's "
                  f"area ({where}); the rest renders as background and is masked (NaN, element −1) in "
                  f"the truth — {fix}", RenderWarning, stacklevel=2)
    return frac
