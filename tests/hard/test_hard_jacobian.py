"""Hard cases, image Jacobians (docs/jacobian.md): grazing views up to 89° and a set-up far from
the origin, plain and lit, against a closed form computed here.

A rigid translation δ of the whole plate along its normal n moves the point a pixel's ray meets
from X = d·c/(d·n) (d the pixel's ray, c = n·(plate point), camera frame) by d/(d·n) per mm —
1/cos of the view angle, 57× at 89° — and the material point seen there by d/(d·n) − n. The
image's derivative along that motion is the Jacobian's columns summed with n over every node,
J·(n, n, …), a smooth function of δ on every pixel (no element edge moves relative to the
material), so it is compared with central differences of the grey along the closed-form path:
g(δ) = I(π_ref(X_u(δ))) (and, lit, combined with phong at X(δ) and the plate's normal), with the
reference interpolant (bspline3, C²) and the camera projections glsim renders with. The
Jacobian's path (implicit differentiation, the interpolant's analytic gradient,
phong_gradient) is not used for the reference.

Tolerance: the differences step the reference point by ≤ 2e-3 px; for a C² cubic B-spline their
truncation is below 1e-7 of the gradient and their rounding below 1e-9 of it, so 1e-5 of the
largest entry (plus the same share of the entry) bounds both with margin; the Jacobian itself is
float64 from a float64 raster. Pixels within 1 px of the plate's outline are left out (their
samples' coverage is not smooth in δ).
"""
import warnings

import numpy as np
import pytest
from _shapes import BACKENDS, SHIFT, far_plate, grazing_plate

from glsim.effects import lighting as shade
from glsim.errors import RenderWarning
from glsim.render import Renderer
from glsim.scene.camera import project_camera_frame, to_camera
from glsim.imaging import interp

# mm of δ per difference step; far from the origin the path's world positions (~2e5 mm, ulp
# 2.9e-11 mm) round by ~1e-5 of 2δ at 1e-6, so there δ = 1e-4 (the reference point then steps
# by ~2e-3 px, the plate being seen head-on)
EPS = {"far": 1e-4}
LIGHT_CAM = np.array([40.0, -30.0, 0.0])   # the light beside camera 0 (its frame, mm)


def _lighting(cam) -> dict:
    """A point light with attenuation and a highlight, at LIGHT_CAM in ``cam``'s frame."""
    position = (LIGHT_CAM - np.asarray(cam.t)) @ np.asarray(cam.R)
    return {"ambient": -0.02, "diffuse": 0.6, "specular": 0.4, "shininess": 6.0, "combine": "multiplicative",
            "lights": [{"position": position.tolist(), "intensity": 0.6, "attenuation": 1e-6}]}


def _closed_form_derivative(r, plate_R, plate_t, lit, eps):
    """Per pixel: dg/dδ from central differences along the closed-form path, and where the
    pixel's ray meets the plate (camera frame of camera 0)."""
    cam, ref_cam, opts = r.scene.cameras[0], r.reference.camera, r.scene.render
    coeffs = interp.prepare(r.reference.image, opts.interpolation, np.float64)
    W, H = cam.size
    n = plate_R[:, 2]
    c = n @ (plate_t + SHIFT)                          # the deformed plate's plane, camera frame
    q = np.stack(np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float)), -1).reshape(-1, 2)
    d = np.column_stack([(q[:, 0] - cam.cx) / cam.fx, (q[:, 1] - cam.cy) / cam.fy, np.ones(len(q))])
    to_world = lambda Xc: (Xc - np.asarray(cam.t)) @ np.asarray(cam.R)  # noqa: E731

    def grey(delta):
        Xd = d * ((c + delta) / (d @ n))[:, None]
        g = interp.sample(coeffs, project_camera_frame(to_camera(to_world(Xd - SHIFT - delta * n), ref_cam), ref_cam)[0],
                          opts.interpolation)
        if not lit:
            return g
        L = _lighting(cam)
        lights = shade.lights_to_camera(L["lights"], np.asarray(cam.R), np.asarray(cam.t))
        I = shade.phong(Xd, np.broadcast_to(n, Xd.shape), lights, L["ambient"], L["diffuse"], L["specular"],
                        L["shininess"])
        return shade.combine(g, I, L["combine"])

    return (grey(eps) - grey(-eps)) / (2 * eps)


@pytest.mark.parametrize("lit", [False, True])
@pytest.mark.parametrize("case", ["0°", "60°", "85°", "89°", "far"])
@pytest.mark.parametrize("backend", BACKENDS)
def test_jacobian_along_the_normal_matches_the_closed_form(backend, case, lit, ctx_for):
    scene, mesh, (_, _, outline) = far_plate() if case == "far" else grazing_plate(float(case[:-1]))
    scene = scene.replace(render={"mode": "exact", "interpolation": "bspline3"},
                          **({"lighting": _lighting(scene.cameras[0])} if lit else {}))
    plate_R, plate_t = _plate_pose(case)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        with Renderer(scene, backend, ctx=ctx_for(backend), mesh=mesh) as r:
            res = r.render(0, 1, jacobian=True)
            cam = r.scene.cameras[0]
            n_world = np.asarray(cam.R).T @ plate_R[:, 2]
            along = res.jacobian @ np.tile(n_world, mesh.n_nodes)
            expected = _closed_form_derivative(r, plate_R, plate_t, lit, EPS.get(case, 1e-6))
    assert np.isfinite(res.jacobian.data).all()
    inside, outside = outline.ravel() > 1.0, outline.ravel() < -1.0
    assert inside.sum() > 300 and not along[outside].any()
    scale = np.abs(expected[inside]).max()
    err = np.abs(along - expected)[inside]
    assert np.all(err <= 1e-5 * (scale + np.abs(expected[inside]))), (err.max(), scale)


def _plate_pose(case):
    """The plate's pose (R, t) in camera 0's frame, as test_hard_geometry places it."""
    from test_hard_coverage import rotation

    if case == "far":
        return rotation(25, 35, 20), np.array([0.2, -0.1, 300.0])
    return rotation(0, float(case[:-1]), 0), np.array([0.0, 0.0, 300.0])
