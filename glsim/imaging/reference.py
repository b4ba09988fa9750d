"""Stages "scene → mesh" and "scene → reference": the placed FE mesh and the reference speckle
image with the virtual reference camera that took it (paper §2.1, Fig. 1)."""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from glsim.io import images
from glsim.scene import mesh as meshmod
from glsim.scene import speckle
from glsim.scene.camera import Camera, project_camera_frame, to_camera
from glsim.errors import RenderWarning, SceneError
from glsim.limits import MIN_DOTS_ACROSS, check_image_size
from glsim.imaging.view import extent, mesh_element_areas
from glsim.scene import Scene

MARGIN_PX = 8  # reference-image border around the specimen's projection
FLAT_REL = 1e-12  # largest element area ≤ this × the nodes' box diagonal²: the specimen has no area (float
#                   rounding of collinear corners gives ~2e-16 of it)


@dataclass(frozen=True, eq=False)
class Reference:
    """The reference image (float32 (H, W) in [0, 1]) and its pinhole camera; for the
    built-in generator also its dots, which ``interpolation = "procedural"`` evaluates
    exactly instead of interpolating the image."""
    image: np.ndarray
    camera: Camera
    dots: speckle.Dots | None = None


def specimen_frame(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """The specimen's pose (R, t): world = R · specimen + t, mm."""
    return np.asarray(scene.specimen.R, float), np.asarray(scene.specimen.t, float)


@dataclass(frozen=True, eq=False)
class Placement:
    """Where the reference image sits on the undeformed specimen, in the specimen's own frame
    (mm, before ``specimen.pose``): the image faces the unit normal ``n`` (the reference camera
    looks along −n), its u axis runs along ``u`` and v along ``v`` = u × n (seen from +n the
    image is not mirrored), and its centre pixel sees the point ``C`` (for the generator, whose
    image is sized to the specimen: the point its optical axis meets)."""
    C: np.ndarray
    n: np.ndarray
    u: np.ndarray
    v: np.ndarray
    half_diagonal: float  # of the specimen's bounding box along u, v, n


def surface_normal(points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Unit normal of the weighted points' best-fit plane (the direction of least second
    moment), snapped to the nearest coordinate axis when within 1e-12 of it, sign not fixed."""
    total = weights.sum()
    c = weights @ points / (total if total > 0 else 1.0)
    d = points - c
    moments = np.einsum("n,ni,nj->ij", weights, d, d)
    if not (total > 0 and np.isfinite(moments).all()):   # eigh would fail with LinAlgError
        raise SceneError("specimen", "has no surface to fit a plane to (no area, or coordinates too large)",
                         "check the mesh's node coordinates and connectivity")
    _, vecs = np.linalg.eigh(moments)
    n = vecs[:, 0]
    i = int(np.argmax(np.abs(n)))
    if abs(n[i]) > 1 - 1e-12:
        n = np.eye(3)[i] * np.sign(n[i])
    return n / np.linalg.norm(n)


def placement_of(local: np.ndarray, samples: np.ndarray, weights: np.ndarray, toward: np.ndarray, centre=(),
                 u_axis=(1.0, 0.0, 0.0), normal=()) -> Placement:
    """The :class:`Placement` for a specimen with undeformed nodes ``local`` and surface
    quadrature points ``samples`` with ``weights`` (areas), in its own frame; ``toward``:
    camera 0's centre in that frame.

    n: ``normal``, or the normal of the surface's best-fit plane (area-weighted, so that it
    does not depend on the meshing; ±Z for a specimen in its X–Y plane) turned towards camera
    0. u: ``u_axis`` (default +X; +Y where +X lies within 26° of n) made orthogonal to n.
    C: ``centre`` ([X, Y] keeps the default Z) or the centre of the nodes' bounding box along
    u, v, n (the centre of the undeformed bounding box for a specimen in its X–Y plane). All of
    it depends on the specimen's shape and outline only."""
    if len(normal):
        n = np.asarray(normal, float) / np.linalg.norm(normal)
    else:
        n = surface_normal(samples, weights)
        mid = (local.min(axis=0) + local.max(axis=0)) / 2
        if np.dot(toward - mid, n) < 0:
            n = -n
    u = np.asarray(u_axis, float)
    if not len(normal) and tuple(u_axis) == (1.0, 0.0, 0.0) and abs(n[0]) > 0.9:
        u = np.array([0.0, 1.0, 0.0])
    u = u - np.dot(u, n) * n
    u /= np.linalg.norm(u)
    v = np.cross(u, n)
    axes = np.stack([u, v, n])
    a = local @ axes.T                                          # coordinates along u, v, n
    lo, hi = a.min(axis=0), a.max(axis=0)
    C = axes.T @ ((lo + hi) / 2)
    C[:len(centre)] = centre
    return Placement(C=C, n=n, u=u, v=v, half_diagonal=float(np.linalg.norm(hi - lo)) / 2 or 1.0)


def placement(scene: Scene, mesh: meshmod.Mesh) -> Placement:
    """The reference image's placement for ``scene`` and its placed ``mesh`` (``speckle``'s
    ``centre``, ``u_axis`` and ``normal``, see :func:`placement_of`)."""
    R, t = specimen_frame(scene)
    pts, area = _element_samples(mesh)
    sp = scene.speckle
    return placement_of((mesh.nodes - t) @ R, (pts.reshape(-1, 3) - t) @ R, np.repeat(area, pts.shape[1]),
                        (scene.cameras[0].center - t) @ R, sp.centre, sp.u_axis, sp.normal)


def placement_camera(pl: Placement, nodes: np.ndarray, R: np.ndarray, t: np.ndarray, mm_per_px: float,
                     size: tuple[int, int] | None) -> Camera:
    """A pinhole camera looking square onto the specimen along −n from the side it faces, image
    x along u and y along v (``pl`` in the specimen's frame, which ``R``, ``t`` place in the
    world; ``nodes``: the placed mesh's, world).

    Its distance is ten times the half-diagonal of the specimen's bounding box, so the
    projection of a flat specimen is a similarity at ``mm_per_px``. With ``size`` (W, H) the
    image's centre pixel ((W − 1)/2, (H − 1)/2) sees C; with ``size`` None the image is sized to
    the specimen's projection plus a margin of MARGIN_PX to MARGIN_PX + 1, its pixel centres on
    the lattice (a, b) = (X·u, X·v) ∈ mm_per_px·ℤ² of the plane through C (the specimen frame's
    origin, seen along n, falls on a pixel centre): the pixels sit at the same material points
    however far the mesh reaches."""
    dist = 10.0 * pl.half_diagonal
    eye = R @ (pl.C + dist * pl.n) + t
    Rc = np.stack([R @ pl.u, R @ pl.v, -(R @ pl.n)])       # rows: camera x, y, z in the world
    tc = -Rc @ eye
    f = dist / mm_per_px
    probe = Camera(name="reference", size=(1, 1), fx=f, fy=f, cx=0.0, cy=0.0,
                   R=tuple(map(tuple, Rc)), t=tuple(tc))
    if size is None:
        uv, _ = project_camera_frame(to_camera(nodes, probe), probe)
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        origin = -np.array([np.dot(pl.C, pl.u), np.dot(pl.C, pl.v)]) / mm_per_px   # the origin's foot, px
        # pixel 0's lattice point; ±1e-6 px: an outline on the lattice (a plate's edge at the origin)
        # gets the same image, not one that float rounding of the nodes makes a pixel larger
        first = origin + np.floor(lo - MARGIN_PX - origin + 1e-6)
        W, H = (int(math.ceil(x - 1e-6)) + MARGIN_PX + 1 for x in hi - first)
        cx, cy = -first
    else:
        W, H = size
        cx, cy = (W - 1) / 2, (H - 1) / 2
    return Camera(name="reference", size=(W, H), fx=f, fy=f, cx=float(cx), cy=float(cy), R=probe.R, t=probe.t)


def reference_camera(scene: Scene, mesh: meshmod.Mesh, mm_per_px: float, size: tuple[int, int] | None) -> Camera:
    """The automatic reference camera of ``scene`` for its placed ``mesh`` (:func:`placement`,
    :func:`placement_camera`)."""
    R, t = specimen_frame(scene)
    return placement_camera(placement(scene, mesh), mesh.nodes, R, t, mm_per_px, size)


def _auto_camera(nodes: np.ndarray, toward: np.ndarray, mm_per_px: float,
                 size: tuple[int, int] | None) -> Camera:
    """The default placement's camera for a point cloud taken as the specimen in its own frame
    (world = specimen coordinates; the nodes, equally weighted, stand in for the surface).
    Scenes use :func:`reference_camera`, which weights the surface by area."""
    nodes = np.asarray(nodes, float)
    pl = placement_of(nodes, nodes, np.ones(len(nodes)), np.asarray(toward, float))
    return placement_camera(pl, nodes, np.eye(3), np.zeros(3), mm_per_px, size)


def camera_scale(cam: Camera, points: np.ndarray) -> float:
    """Mean mm per pixel of ``cam`` at the centre of the bounding box of ``points`` (world,
    mm; a point that does not depend on how the specimen is meshed)."""
    z = to_camera((points.min(axis=0) + points.max(axis=0)) / 2, cam)[2]
    return float(z / math.sqrt(cam.fx * cam.fy))


def pattern_scale(cam: Camera, pl: Placement, local: np.ndarray, R: np.ndarray, t: np.ndarray) -> float:
    """The generator's unit: camera 0's (``cam``) mean mm per px on the specimen, which turns
    ``dot_diameter_px`` and ``edge_px`` into mm (and, over ``oversample``, gives the reference
    image's mm per px).

    Taken where camera 0's optical axis meets the plane of the placement ``pl`` (through C,
    normal n), that point moved into the bounding box of the nodes ``local`` along u and v if it
    lies outside; at C if the axis meets the plane behind the camera or runs along it (``R``,
    ``t``: the specimen's pose). For a flat specimen that camera 0 looks at, this depends on the
    camera and the specimen's plane only, not on its meshing or on how far it reaches (the old
    point, the bounding box's centre, moves with the extent). It is not rounded: it varies
    continuously, so float rounding of the nodes moves the dots by float rounding only."""
    eye = (cam.center - t) @ R                                   # the specimen's frame
    axis = cam.rotation[2] @ R                                   # the optical axis, Rcᵀ·ẑ
    P = pl.C
    across = float(np.dot(axis, pl.n))
    if across != 0.0:
        lam = float(np.dot(pl.C - eye, pl.n)) / across
        if lam > 0:
            P = eye + lam * axis
            for e in (pl.u, pl.v):                               # into the bounding box along u, v
                a = local @ e
                x = float(np.dot(P, e))
                if not a.min() <= x <= a.max():
                    P = P + (min(max(x, a.min()), a.max()) - x) * e
    s = camera_scale(cam, (R @ P + t)[None])
    return s if s > 0 else camera_scale(cam, (R @ pl.C + t)[None])   # P behind camera 0: C


def _surface_dots(pl: Placement, cam: Camera, mm_per_px: float, dot_mm: float, edge_mm: float, sp) -> speckle.Dots:
    """The generator's dots for the automatic reference camera ``cam`` of placement ``pl``:
    drawn in mm on the plane through C in its coordinates (a, b) = (X·u, X·v) of the specimen
    frame (:func:`speckle.draw_pattern`, lattice anchored at the frame's origin), then mapped
    to the image's px, where that plane projects as a similarity: u = cx + (a − C·u)/mm_per_px,
    v = cy + (b − C·v)/mm_per_px."""
    W, H = cam.size
    c_ab = np.array([np.dot(pl.C, pl.u), np.dot(pl.C, pl.v)])
    c_px = np.array([cam.cx, cam.cy])
    lo = c_ab + (np.array([-0.5, -0.5]) - c_px) * mm_per_px        # the image's footprint, mm
    hi = c_ab + (np.array([W - 0.5, H - 0.5]) - c_px) * mm_per_px
    centres, radii = speckle.draw_pattern(lo, hi, dot_mm, sp.density, sp.seed, edge_mm)
    return speckle.Dots((centres - c_ab) / mm_per_px + c_px, radii / mm_per_px, edge_mm / mm_per_px,
                        speckle.BLACK, speckle.WHITE, (H, W))


def make_reference(scene: Scene, mesh: meshmod.Mesh) -> Reference:
    """The reference image and camera: loaded or generated, as the scene's [speckle] says.
    Raises SceneError when the reference image leaves part of the specimen without pattern."""
    sp = scene.speckle
    cam1 = scene.cameras[0]
    require_area(mesh, "specimen.mesh.path" if scene.specimen.mesh is not None else "specimen")
    if sp.image:
        image = images.load_reference(scene.resolve(sp.image))
        if sp.camera is not None:
            cam = sp.camera
            if (cam.width, cam.height) != image.shape[::-1]:
                raise SceneError("speckle.camera.size", f"{cam.size} differs from the image's "
                                 f"{image.shape[::-1]}", "give the reference image's size")
            require_coverage(mesh, cam, "speckle.camera")
        else:  # the scene requires mm_per_px > 0 when there is no camera
            pl = placement(scene, mesh)
            R, t = specimen_frame(scene)
            cam = placement_camera(pl, mesh.nodes, R, t, sp.mm_per_px, image.shape[::-1])
            require_coverage(mesh, cam, "speckle.image", sp.mm_per_px, (R, t), (pl.C, pl.n))
        return Reference(image, cam)
    # The generator: dots in mm, sized in camera-0 px by pattern_scale (not by the mesh's extent).
    R, t = specimen_frame(scene)
    pl = placement(scene, mesh)
    cam_mm_per_px = pattern_scale(cam1, pl, (mesh.nodes - t) @ R, R, t)
    if not cam_mm_per_px > 0:
        _refuse_facing(cam1, R @ pl.C + t)
    mm_per_px = sp.mm_per_px or cam_mm_per_px / sp.oversample
    cam = sp.camera or placement_camera(pl, mesh.nodes, R, t, mm_per_px, None)
    if sp.camera is not None:
        require_coverage(mesh, cam, "speckle.camera")
    check_image_size("speckle.mm_per_px" if sp.mm_per_px else "speckle.oversample", cam.width, cam.height,
                     f"the generated reference image (camera {cam1.name} sees {cam_mm_per_px:.3g} mm per px on the "
                     f"specimen, over speckle.oversample = {sp.oversample:g})",
                     "give a larger mm_per_px or a smaller oversample, or check cameras[0].fx and its distance")
    dot_mm = sp.dot_diameter_px * cam_mm_per_px
    edge_mm = min(sp.edge_px * cam_mm_per_px, dot_mm)
    dot = dot_mm / mm_per_px
    _check_dot(dot, cam, sp.dot_diameter_px)
    if sp.camera is not None:   # a given camera: the dots lie in its image (px), which the scene fixes
        dots = speckle.draw_dots((cam.height, cam.width), dot, sp.density, seed=sp.seed, edge_px=edge_mm / mm_per_px)
    else:
        speckle.pattern_args(dot, sp.density, edge_mm / mm_per_px)   # at least 2 reference px, as draw_dots
        dots = _surface_dots(pl, cam, mm_per_px, dot_mm, edge_mm, sp)
    return Reference(speckle.rasterize(dots), cam, dots)


def _refuse_facing(cam: Camera, centre) -> None:
    """The SceneError for a camera 0 that does not face the specimen (its scale at the specimen,
    which sizes the generated dots, is not positive): ``centre`` (world mm) is the point of the
    specimen the scale was taken at."""
    z = float(to_camera(centre, cam)[2])
    why = (f"looks away from the specimen: the specimen's centre lies {-z:.4g} mm behind it" if z < 0 else
           "sees the specimen edge-on or not at all: the specimen's centre lies 0 mm in front of it (in the plane "
           "through the camera's centre square to its optical axis)")
    raise SceneError("cameras[0]", f"camera {cam.name} {why}, so the built-in speckle generator cannot size its "
                     "dots in this camera's pixels", "turn it to the specimen (cameras[0].pose, e.g. look_at) or move "
                     "the specimen in front of it (specimen.pose.t: +z is in front of a camera without a pose), "
                     "or give a speckle.image with speckle.mm_per_px")


def require_area(mesh: meshmod.Mesh, key: str) -> None:
    """SceneError(key) when no element of the undeformed ``mesh`` has an area — its nodes all
    equal, on one line, or every element collapsed — rather than a failed plane fit: the
    reference image could not be laid on it and no pixel would see it. An element counts as
    having none at or below FLAT_REL of the nodes' bounding box's diagonal squared."""
    lo, hi = extent(mesh.nodes)
    area, _ = mesh_element_areas(mesh.nodes - (lo + hi) / 2, mesh.quads)
    span = hi - lo
    largest = float(area.max())
    if largest > FLAT_REL * float(span @ span):
        return
    d = (mesh.nodes - (lo + hi) / 2) / max(float(span.max()), 1e-300)
    sv = np.linalg.svd(d.T @ d, compute_uv=False)
    why = ("all its nodes coincide" if not span.any() else "all its nodes lie on one line"
           if sv[1] <= FLAT_REL * sv[0] else "every element is collapsed (corners coincide or lie on one line)")
    raise SceneError(key, f"no element has an area: {why} (the largest element area is {largest:.3g} mm², the "
                     f"{len(mesh.nodes)} nodes span {' × '.join(f'{v:.4g}' for v in span)} mm)",
                     "check the mesh's node coordinates and element connectivity (and specimen.mesh.unit)")


def _check_dot(dot: float, cam: Camera, camera_px: float) -> None:
    """Refuse a speckle dot (``dot`` reference px) larger than the reference image; warn
    (RenderWarning) when fewer than MIN_DOTS_ACROSS fit across it: the pattern cannot be seen."""
    across = min(cam.width, cam.height) / dot
    if across < 1:
        raise SceneError("speckle.dot_diameter_px", f"{camera_px:g} px makes dots of {dot:.4g} reference px, larger "
                         f"than the reference image ({cam.width} × {cam.height} px)", "give dots of 3–10 px, e.g. 5")
    if across < MIN_DOTS_ACROSS:
        warnings.warn(f"speckle.dot_diameter_px = {camera_px:g} px: only {across:.2g} dots fit across the specimen, "
                      "so the pattern cannot be seen (a blank or single-blob image); give dots of 3–10 px",
                      RenderWarning, stacklevel=3)


def _element_samples(mesh: meshmod.Mesh, n: int = 4):
    """n×n points per undeformed element (world, mm) and the elements' areas."""
    q = mesh.nodes[mesh.quads]                                        # (M, 4, 3)
    g = (np.arange(n) + 0.5) / n * 2 - 1
    xi, eta = (a.ravel() for a in np.meshgrid(g, g))
    w = np.stack([(1 - xi) * (1 - eta), (1 + xi) * (1 - eta), (1 + xi) * (1 + eta), (1 - xi) * (1 + eta)], 1) / 4
    pts = np.einsum("sk,mkd->msd", w, q)                              # (M, n², 3)
    area = 0.5 * (np.linalg.norm(np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]), axis=1)
                  + np.linalg.norm(np.cross(q[:, 2] - q[:, 0], q[:, 3] - q[:, 0]), axis=1))
    return pts, area


def _inside(uv: np.ndarray, ok: np.ndarray, cam: Camera, tol: float = 0.0) -> np.ndarray:
    """Reference points inside the image as the renderers count them: u in [−0.5, W − 0.5],
    v in [−0.5, H − 0.5] (``tol`` px more on each side)."""
    W, H = cam.size
    return (ok & (uv[..., 0] >= -0.5 - tol) & (uv[..., 0] <= W - 0.5 + tol)
            & (uv[..., 1] >= -0.5 - tol) & (uv[..., 1] <= H - 0.5 + tol))


def coverage(mesh: meshmod.Mesh, cam: Camera, n: int = 4) -> float:
    """The fraction of the undeformed specimen's area that ``cam`` (the reference camera) sees
    inside its image, from n×n points per element weighted by element area."""
    pts, area = _element_samples(mesh, n)
    uv, ok = project_camera_frame(to_camera(pts, cam), cam)
    total = float(area.sum()) * n * n
    return float((_inside(uv, ok, cam) * area[:, None]).sum() / total) if total > 0 else 1.0


def require_coverage(mesh: meshmod.Mesh, cam: Camera, key: str, mm_per_px: float = 0.0, frame=None,
                     plane=None, tol_px: float = 1e-6) -> None:
    """Raise SceneError when the reference image leaves part of the undeformed specimen (its
    nodes and 4×4 points per element) without pattern, naming the covered share of the area,
    the extent of the specimen and of the part the image covers, in the specimen's frame
    (``frame`` = (R, t); the world's if None) and in image px, and the fix. ``plane`` = (C, n)
    in the specimen's frame: the plane the image is laid on (the automatic camera's); the
    image's footprint is its border projected onto it. ``mm_per_px`` > 0: the automatic camera
    of ``speckle.image`` (the fix then says which image size or scale covers the specimen).
    The renderers count samples outside the reference image with the same bounds
    (u in [−0.5, W − 0.5], v in [−0.5, H − 0.5]): after this check they find none."""
    pts, _ = _element_samples(mesh)
    pts = np.concatenate([mesh.nodes, pts.reshape(-1, 3)])
    uv, ok = project_camera_frame(to_camera(pts, cam), cam)
    if _inside(uv, ok, cam, tol_px).all():
        return
    W, H = cam.size
    R, t = frame if frame is not None else (np.eye(3), np.zeros(3))
    local = (mesh.nodes - t) @ R

    def spans(a, b):
        return ", ".join(f"{'XYZ'[i]} {a[i]:.4g}…{b[i]:.4g}" for i in range(3) if b[i] - a[i] > 1e-9 * (1 + abs(b[i])))

    where = f"the specimen spans {spans(local.min(axis=0), local.max(axis=0))} mm"
    if plane is not None:  # the image's border on the plane it is laid on
        C, n = (np.asarray(x, float) for x in plane)
        corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]])
        rays = np.column_stack([(corners[:, 0] - cam.cx) / cam.fx, (corners[:, 1] - cam.cy) / cam.fy,
                                np.ones(4)]) @ np.asarray(cam.R)          # world directions
        eye = -np.asarray(cam.R).T @ np.asarray(cam.t)
        nw, Cw = R @ n, R @ C + t
        foot = (eye + rays * (np.dot(Cw - eye, nw) / (rays @ nw))[:, None] - t) @ R
        where = f"the image covers {spans(foot.min(axis=0), foot.max(axis=0))} mm of it, {where}"
    lo, hi = uv[ok].min(axis=0), uv[ok].max(axis=0)
    where += (f" (in its own frame; in the {W}×{H} px image it spans u {lo[0]:.1f}…{hi[0]:.1f}, "
              f"v {lo[1]:.1f}…{hi[1]:.1f} px, of u, v −0.5…{W - 0.5:g}, {H - 0.5:g})")
    if not ok.all():
        where += f"; {int((~ok).sum())} of its points lie behind the reference camera"
    if mm_per_px > 0:
        c = np.array([cam.cx, cam.cy])
        need = [math.ceil(2 * max(abs(lo[i] - c[i]), abs(hi[i] - c[i]))) + 1 for i in (0, 1)]
        scale = mm_per_px * max(need[0] / W, need[1] / H)
        fix = (f"give an image of at least {need[0]}×{need[1]} px at {mm_per_px:g} mm/px, set "
               f"speckle.mm_per_px ≥ {scale:.4g} to stretch this one over the specimen, or move it with "
               f"speckle.centre")
        what = f"the {W}×{H} px image ({W * mm_per_px:.4g}×{H * mm_per_px:.4g} mm at {mm_per_px:g} mm/px)"
    else:
        fix = "give a larger image, or a speckle.camera that sees the whole specimen"
        what = "the reference image"
    raise SceneError(key, f"{what} would leave part of the specimen without pattern, {100 * (1 - coverage(mesh, cam)):.3g} % "
                     f"of its area: {where}", fix)


def require_dots(dots):
    """The reference's dots, or the error that says procedural needs the generator."""
    if dots is None:
        raise SceneError("render.interpolation", "'procedural' needs the built-in speckle generator",
                         "remove [speckle] image, or choose linear, cubic, bspline3 or bspline5")
    return dots
