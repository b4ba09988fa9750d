"""``glsim bench quadratic``: quadratic elements' mapping error and time per backend × mode
against a closed form.

The specimen is the paraboloid z = ZC + A x² + C y² (30 × 24 mm at 400 mm) meshed with Q8
and with T6 elements on a lattice affine in (x, y), which represents it exactly, moved by a
translation plus uz = B x² + D x y (also exact). Every pixel's ray meets it in closed form, so
the reference-image point each pixel should show is known: the mapping error is
|truth.ref_uv − closed form| in reference-image px, the position error |X_deformed − closed
form| in mm, at pixel centres (1 spp), over the pixels both cover 2 px or more inside the
outline. Times: median of renders without truth (GL: 3, CPU oracle: 1 for q4/exact), ratios to
GL exact of the same mesh first. Writes quadratic.{json,md} (bench/results for the full run at
480×400, build/bench otherwise).
"""
from __future__ import annotations

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


def paraboloid_scene(size: tuple[int, int]) -> Scene:
    """The camera before the paraboloid, ``size`` px (its mesh: :func:`mesh`, given to the Renderer)."""
    W, H = size
    f = 0.9 * min(W * ZC / W0, H * ZC / H0)
    cam = Camera(name="c", size=(W, H), fx=f, fy=f, cx=(W - 1) / 2 + 0.3, cy=(H - 1) / 2 - 0.4)
    return Scene(cameras=(cam,), specimen=Specimen(plate=Plate(width=1, height=1, nx=1, ny=1)))


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
    return {"map_mean": float(dm.mean()), "map_max": float(dm.max()), "X_max": float(dx.max()), "pixels": int(m.sum()),
            "time": float(np.median(times))}


FULL_SIZE = (480, 400)
MESHES = (("quad8", (4, 3), (2, 4, 8)), ("triangle6", (4, 3), (4,)))


def quadratic(size=FULL_SIZE) -> dict:
    """Every backend × mode row for the Q8 and the T6 mesh of the paraboloid at ``size``."""
    from glsim.bench.report import gl_info, machine_info

    W, H = size
    scene = paraboloid_scene(size)
    Xu, Xd, inner = closed_form(scene.cameras[0])
    report = {"size": [W, H], "date": time.strftime("%Y-%m-%d"), "meshes": []}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        for kind, (nx, ny), pieces in MESHES:
            m, rows = mesh(kind, nx, ny), []
            for backend in ("cpu", "gl"):
                for n in pieces:
                    with Renderer(scene.replace(render={"pieces": n}), backend, mesh=m) as r:
                        rows.append({"backend": backend, "mode": "fast", "pieces": n,
                                     **measure(r, "fast", Xu, Xd, inner)})
                with Renderer(scene, backend, mesh=m) as r:
                    if backend == "gl":
                        report.setdefault("machine", machine_info(gl_info(r)))
                    for mode in ("q4", "exact"):
                        rows.append({"backend": backend, "mode": mode, "pieces": None,
                                     **measure(r, mode, Xu, Xd, inner, reps=1 if backend == "cpu" else 3)})
            report["meshes"].append({"kind": kind, "elements": len(m.patches), "grid": [nx, ny],
                                     "element_px": scene.cameras[0].fx * W0 / nx / ZC, "rows": rows})
    return report


def mode_label(row: dict) -> str:
    return f"fast ({row['pieces']}×{row['pieces']} pieces)" if row["mode"] == "fast" else \
        row["mode"] + (" (fp64)" if row["backend"] == "gl" else "")


def markdown(report: dict) -> str:
    from glsim.bench.report import machine_line

    W, H = report["size"]
    out = ["# Quadratic elements: mapping error and time against the closed form\n",
           f"{W}×{H} px, {report['date']}; {machine_line(report['machine'])}. Times without truth, "
           "medians; ratios to GL exact of the same mesh."]
    for m in report["meshes"]:
        exact = next(r["time"] for r in m["rows"] if r["backend"] == "gl" and r["mode"] == "exact")
        out += [f"\n## {m['kind']}: {m['elements']} elements on {m['grid'][0]} × {m['grid'][1]} cells of about "
                f"{m['element_px']:.0f} px\n",
                "| backend | mode | mapping error mean / max (ref px) | X error max (mm) | time / GL exact | time (s) |",
                "|---|---|---|---|---|---|"]
        out += [f"| {r['backend']} | {mode_label(r)} | {r['map_mean']:.2e} / {r['map_max']:.2e} | {r['X_max']:.2e} | "
                f"{r['time'] / exact:.2g} | {r['time']:.3g} |" for r in m["rows"]]
    return "\n".join(out) + "\n"


def write(report: dict, out) -> str:
    """quadratic.json and quadratic.md into ``out``; returns the markdown."""
    from glsim.bench.report import write_results
    return write_results(report, markdown(report), out, "quadratic")
