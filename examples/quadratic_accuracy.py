"""Quadratic elements: mapping error and time per backend × mode against the closed form.

The specimen is the paraboloid z = ZC + A x² + C y² (30 × 24 mm at 400 mm) meshed with Q8
(or T6) elements on a lattice affine in (x, y), which represents it exactly, moved by a
translation plus uz = B x² + D x y (also exact). Every pixel's ray meets it in closed form, so
the reference-image point each pixel should show is known: the mapping error is
|truth.ref_uv − closed form| in reference-image px, the position error |X_deformed − closed
form| in mm, at pixel centres (1 spp), over the pixels both cover away (2 px) from the outline.

    .venv/bin/python examples/quadratic_accuracy.py [--gl] [--size 480x400] [--pieces 2,4,8]

Prints a markdown table (docs/quadratic.md quotes it).
"""
from __future__ import annotations

import argparse
import platform
import time
import warnings

import numpy as np

from glsim.errors import RenderWarning
from glsim.render import Renderer
from glsim.scene import Plate, Scene, Specimen
from glsim.scene import quadratic as qd
from glsim.scene.camera import Camera, project_camera_frame, to_camera
from glsim.scene.mesh import Mesh

ZC, W0, H0 = 400.0, 30.0, 24.0
A, C, B, D = 0.01, 0.006, 0.004, -0.002
SHIFT = np.array([0.21, -0.13, 0.37])


def mesh(kind: str, nx: int, ny: int) -> Mesh:
    xs, ys = np.linspace(-W0 / 2, W0 / 2, 2 * nx + 1), np.linspace(-H0 / 2, H0 / 2, 2 * ny + 1)
    X, Y = np.meshgrid(xs, ys)
    nodes = np.stack([X.ravel(), Y.ravel(), ZC + A * X.ravel() ** 2 + C * Y.ravel() ** 2], 1)
    at = np.arange(X.size).reshape(X.shape).T     # at[i, j]: column i, row j
    rows = []
    for j in range(ny):
        for i in range(nx):
            c, r = 2 * i, 2 * j
            if kind == "quad8":
                rows.append([at[c, r], at[c + 2, r], at[c + 2, r + 2], at[c, r + 2], at[c + 1, r], at[c + 2, r + 1],
                             at[c + 1, r + 2], at[c, r + 1], qd.CENTRE_Q8])
            else:
                for a, b, cc, m1, m2, m3 in ((at[c, r], at[c + 2, r], at[c + 2, r + 2], at[c + 1, r], at[c + 2, r + 1],
                                              at[c + 1, r + 1]),
                                             (at[c, r], at[c + 2, r + 2], at[c, r + 2], at[c + 1, r + 1],
                                              at[c + 1, r + 2], at[c, r + 1])):
                    rows.append([a, b, cc, cc, m1, m2, cc, m3, qd.CENTRE_T6])
    p = np.array(rows)
    u = np.broadcast_to(SHIFT, nodes.shape).copy()
    u[:, 2] += B * nodes[:, 0] ** 2 + D * nodes[:, 0] * nodes[:, 1]
    return Mesh(nodes, p[:, :4], np.arange(1, len(nodes) + 1), np.arange(1, len(p) + 1),
                (np.zeros_like(nodes), u), patches=p)


def closed_form(cam: Camera):
    W, H = cam.size
    q = np.stack(np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float)), -1)
    u, v = (q[..., 0] - cam.cx) / cam.fx, (q[..., 1] - cam.cy) / cam.fy
    t = SHIFT
    a2 = A + B
    qa = a2 * u * u + C * v * v + D * u * v
    qb = -2 * a2 * u * t[0] - 2 * C * v * t[1] - D * (u * t[1] + v * t[0]) - 1
    qc = ZC + t[2] + a2 * t[0] ** 2 + C * t[1] ** 2 + D * t[0] * t[1]
    s = 2 * qc / (-qb + np.sqrt(qb * qb - 4 * qa * qc))
    Xd = np.stack([u * s, v * s, s], -1)
    x, y = Xd[..., 0] - t[0], Xd[..., 1] - t[1]
    Xu = np.stack([x, y, ZC + A * x ** 2 + C * y ** 2], -1)
    margin = 2 * ZC / cam.fx
    inner = (np.abs(x) < W0 / 2 - margin) & (np.abs(y) < H0 / 2 - margin)
    return Xu, Xd, inner


def measure(r: Renderer, mode: str, Xu, Xd, inner, reps: int = 3) -> dict:
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        r.render(0, 1, mode=mode)
        times.append(time.perf_counter() - t0)
    t = r.render(0, 1, truth=True, mode=mode).truth
    ref_cam = r.reference.camera
    ref_exact, _ = project_camera_frame(to_camera(Xu, ref_cam), ref_cam)
    m = t.mask & inner
    dm = np.linalg.norm(t.ref_uv[m] - ref_exact[m], axis=-1)
    dx = np.linalg.norm(t.X_deformed[m] - Xd[m], axis=-1)
    return {"map_mean": dm.mean(), "map_max": dm.max(), "X_max": dx.max(), "pixels": int(m.sum()),
            "time": float(np.median(times))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gl", action="store_true", help="also the GL backend")
    ap.add_argument("--size", default="480x400")
    ap.add_argument("--kind", default="quad8", choices=("quad8", "triangle6"))
    ap.add_argument("--elements", default="4x3")
    ap.add_argument("--pieces", default="2,4,8")
    args = ap.parse_args()
    W, H = map(int, args.size.split("x"))
    nx, ny = map(int, args.elements.split("x"))
    f = 0.9 * min(W * ZC / W0, H * ZC / H0)
    cam = Camera(name="c", size=(W, H), fx=f, fy=f, cx=(W - 1) / 2 + 0.3, cy=(H - 1) / 2 - 0.4)
    scene = Scene(cameras=(cam,), specimen=Specimen(plate=Plate(width=1, height=1, nx=1, ny=1)))
    m = mesh(args.kind, nx, ny)
    Xu, Xd, inner = closed_form(cam)
    rows = []
    warnings.simplefilter("ignore", RenderWarning)
    backends = ["cpu"] + (["gl"] if args.gl else [])
    for backend in backends:
        for pieces in map(int, args.pieces.split(",")):
            with Renderer(scene, backend, mesh=m, pieces=pieces) as r:
                rows.append((backend, f"fast ({pieces}×{pieces} pieces)", measure(r, "fast", Xu, Xd, inner)))
        with Renderer(scene, backend, mesh=m) as r:
            for mode in ("q4", "exact"):
                rows.append((backend, mode, measure(r, mode, Xu, Xd, inner, reps=1 if backend == "cpu" else 3)))
    print(f"{args.kind}, {nx}×{ny} elements ({W0 / nx:g} × {H0 / ny:g} mm, about {f * W0 / nx / ZC:.0f} px), "
          f"{W}×{H} px, {platform.processor() or platform.machine()}")
    print("| backend | mode | mapping error mean / max (ref px) | X error max (mm) | pixels | time (s) |")
    print("|---|---|---|---|---|---|")
    for backend, mode, v in rows:
        print(f"| {backend} | {mode} | {v['map_mean']:.2e} / {v['map_max']:.2e} | {v['X_max']:.2e} | {v['pixels']} "
              f"| {v['time']:.3f} |")


if __name__ == "__main__":
    main()
