"""Meshes, scenes and checks shared by the hard-case tests: closed-form geometry (rotations,
posed and grazing plates, a plate far from the origin), the render call they all make, and the
bands their truth is held to."""

import warnings

import numpy as np
import pytest

from glsim.backends.gl.context import driver_info
from glsim.errors import RenderWarning
from glsim.check import closed_forms
from glsim.render import Renderer
from glsim.scene import Plate, Scene, Specimen
from glsim.scene.camera import Camera
from glsim.scene.mesh import Mesh

BACKENDS = ["cpu", pytest.param("gl", marks=pytest.mark.gl)]


def rotation(ax_deg, ay_deg, az_deg):
    ax, ay, az = np.radians([ax_deg, ay_deg, az_deg])
    Rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
    Ry = np.array([[np.cos(ay), 0, np.sin(ay)], [0, 1, 0], [-np.sin(ay), 0, np.cos(ay)]])
    Rz = np.array([[np.cos(az), -np.sin(az), 0], [np.sin(az), np.cos(az), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def grid_mesh(xs, ys):
    """Flat grid mesh (z = 0) on node columns xs and rows ys (mm), FE corner order CCW from +z."""
    x, y = np.meshgrid(xs, ys)
    nodes = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    idx = np.arange(x.size).reshape(x.shape)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    return nodes, quads


def custom(nodes, quads, cam, steps=()):
    """A scene with camera ``cam`` and the given mesh (world frame, mm); ``steps``: deformed
    node arrays of load steps 1, 2, …"""
    scene = Scene(cameras=(cam,), specimen=Specimen(plate=Plate(width=1, height=1, nx=1, ny=1)))
    disp = (np.zeros_like(nodes), *(np.asarray(s, float) - nodes for s in steps)) if steps else ()
    mesh = Mesh(nodes=nodes, quads=np.asarray(quads), node_labels=np.arange(1, len(nodes) + 1),
                element_labels=np.arange(1, len(quads) + 1), displacements=disp)
    return scene, mesh


def outline_distance(corners_world, cam):
    """Signed distance (px) of every pixel centre to the pinhole projection of a flat convex
    outline (corners CCW from +z), positive inside: the closed-form coverage."""
    X = corners_world
    uv = np.column_stack([cam.fx * X[:, 0] / X[:, 2] + cam.cx, cam.fy * X[:, 1] / X[:, 2] + cam.cy])
    W, H = cam.size
    q = np.stack(np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float)), -1)
    cross = lambda a, b: a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]  # noqa: E731
    area = sum(cross(uv[k], uv[(k + 1) % 4]) for k in range(4))
    d = np.full((H, W), np.inf)
    for k in range(4):
        a, b = uv[k], uv[(k + 1) % 4]
        e = b - a
        d = np.minimum(d, np.sign(area) * cross(e, q - a) / np.linalg.norm(e))
    return d


def perturbed_grid(nx, ny, w, h, amount, seed):
    """nx × ny grid over w × h mm, interior nodes moved in-plane by up to ``amount`` elements."""
    nodes, quads = grid_mesh(np.linspace(-w / 2, w / 2, nx + 1), np.linspace(-h / 2, h / 2, ny + 1))
    rng = np.random.default_rng(seed)
    x, y = nodes[:, 0], nodes[:, 1]
    interior = (np.abs(x) < w / 2 - 1e-9) & (np.abs(y) < h / 2 - 1e-9)
    step = np.array([w / nx, h / ny])
    nodes[interior, :2] += rng.uniform(-amount, amount, (interior.sum(), 2)) * step
    return nodes, quads


def plane_truth(cam, R, t, shift, H, W):
    """Closed form for a flat plate (plane z = 0 of the pose R, t) moved rigidly by ``shift``:
    each pixel's ray meets the moved plane at X_deformed; X_undeformed = X_deformed − shift."""
    n = R[:, 2]
    c = n @ (np.asarray(t) + shift)
    q = np.stack(np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float)), -1)
    d = np.concatenate([(q[..., :1] - cam.cx) / cam.fx, (q[..., 1:] - cam.cy) / cam.fy,
                        np.ones((H, W, 1))], -1)
    Xd = d * (c / (d @ n))[..., None]
    return Xd - shift, Xd


X_TOL = closed_forms.FLOAT64   # mm: truth of an exact mode against a float64 closed form


def x_err_ok(backend, mode, fx, X, closed):
    """Truth X (H, W, 3) within its bound of the closed form ``closed`` where covered: float64,
    or GL fast's float32 bound per pixel (closed_forms.fast_bound over the closed form's map)."""
    mask = np.isfinite(X).all(-1) & np.isfinite(closed).all(-1)
    err = np.linalg.norm(np.where(mask[..., None], X - closed, 0.0), axis=-1)
    bound = closed_forms.fast_bound(fx, closed, mask) if (backend == "gl" and mode == "fast") else X_TOL
    return bool((err <= bound)[mask].all()), float(err[mask].max(initial=0.0))


def band_px(backend, mode, fx, ctx):
    """Distance from the outline (px) within which a pixel centre's coverage is not asserted:
    GL fast's tie distance (glsim.check.closed_forms.tie_px: float32 vertices, focal length
    ``fx`` px, snapped to the GL context ``ctx``'s GL_SUBPIXEL_BITS), else 1e-6."""
    if backend == "gl" and mode == "fast":
        return closed_forms.tie_px(mode, fx, driver_info(ctx)["GL_SUBPIXEL_BITS"])
    return 1e-6


def rays(cam):
    """Normalized pinhole rays (xn, yn) of every pixel centre, (H, W) each (no distortion)."""
    W, H = cam.size
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    return (u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy


def render(scene, mesh, backend, ctx, mode, step=1):
    """One render with truth; RenderWarnings (named elements, dropped pixels) are ignored here."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        with Renderer(scene, backend, ctx=ctx, mesh=mesh) as r:
            return r.render(0, step, truth=True, mode=mode)


def finite_where_covered(res):
    """No NaN or inf in the image nor in any truth map on the covered pixels."""
    t = res.truth
    maps = (t.X_deformed, t.X_undeformed, t.ref_uv, t.xi[..., None], t.eta[..., None])
    return bool(np.isfinite(res.image).all() and all(np.isfinite(m[t.mask]).all() for m in maps))


PLATE_CAM = Camera(name="c", size=(96, 72), fx=800.0, fy=800.0, cx=47.3, cy=35.6)


SHIFT = np.array([0.0137, -0.021, 0.01])  # mm, rigid translation of step 1 (camera frame)


def posed_plate(R, t, w, h, nx, ny, cam=PLATE_CAM, offset=np.zeros(3)):
    """A w × h mm plate of nx × ny elements in the plane z = 0 of the pose (R, t) in the
    camera frame, moved rigidly by SHIFT at step 1. ``offset``: the whole set-up (camera and
    plate) translated by this in the world. Returns the scene, its mesh and the closed form
    (X_undeformed, X_deformed, signed distance to the projected outline in px)."""
    Rc = np.asarray(cam.R)
    cam = Camera(name=cam.name, size=cam.size, fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy,
                 R=Rc, t=np.asarray(cam.t) - Rc @ offset)
    nodes, quads = grid_mesh(np.linspace(-w / 2, w / 2, nx + 1), np.linspace(-h / 2, h / 2, ny + 1))
    to_world = lambda Xc: (Xc - cam.t) @ Rc  # noqa: E731  (X_cam = R X_world + t)
    Xc = nodes @ R.T + t
    scene, mesh = custom(to_world(Xc), quads, cam, steps=(to_world(Xc + SHIFT),))
    W, H = cam.size
    Xu, Xd = plane_truth(cam, R, t, SHIFT, H, W)
    corners = np.array([[-w / 2, -h / 2, 0], [w / 2, -h / 2, 0], [w / 2, h / 2, 0], [-w / 2, h / 2, 0]])
    return scene, mesh, (Xu, Xd, outline_distance(corners @ R.T + t + SHIFT, cam))


def grazing_plate(angle):
    """A 200 × 30 mm plate at 300 mm turned by ``angle`` about the camera's y axis."""
    return posed_plate(rotation(0, angle, 0), np.array([0.0, 0.0, 300.0]), 200.0, 30.0, 20, 3)


FAR = np.array([5e4, -3e4, 2e5])  # mm


def far_plate(offset=FAR):
    """A tilted 60 × 40 mm plate 300 mm in front of a turned camera, the whole set-up moved
    to ``offset`` in the world (nodes stored at about 2e5 mm: ulp 2.9e-11 mm)."""
    cam = Camera(name="c", size=(96, 72), fx=800.0, fy=800.0, cx=47.3, cy=35.6, R=rotation(10, -20, 5))
    return posed_plate(rotation(25, 35, 20), np.array([0.2, -0.1, 300.0]), 60.0, 40.0, 8, 6,
                       cam=cam, offset=np.asarray(offset, float))
