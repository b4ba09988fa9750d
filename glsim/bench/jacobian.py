"""``glsim bench jacobian``: the time of an image Jacobian (``Renderer.render(..., jacobian=True)``,
docs/jacobian.md) against one render and against finite differences of the nodal Jacobian.

The bulge (step 1, camera 0, exact mode, bspline3) at 1624×1234 by default, per row of ROWS
(backend, samples per pixel, what the scene adds or changes: nothing; mode fast; the lighting or
the depth of field of :func:`glsim.scene.demo_effects`; a 2-sample exposure of a rigid motion;
vignetting and PRNU):
after one warm-up, ``reps`` interleaved pairs of a plain render and a render with the Jacobian;
medians. Finite differences are not run: they cost two renders per degree of freedom (3 per
node), estimated as 2 · 3N times the plain render's median.
"""
from __future__ import annotations

import statistics
import time

from glsim.render import Renderer
from glsim.scene import bulge_scene, demo_effects

FULL_SIZE = (1624, 1234)
QUICK_SIZE = (406, 308)
EXPOSURE = {"time": 0.01, "samples": 2, "velocity": [20.0, 0.0, 0.0]}    # 0.2 mm over the exposure
CAMERA_EFFECTS = {"vignetting": {"natural": True}, "sensor": {"prnu": 1.0}}
ROWS = (("gl", 1, "—"), ("gl", 4, "—"), ("cpu", 1, "—"), ("gl", 1, "mode fast"), ("gl", 4, "mode fast"),
        ("gl", 1, "lighting"), ("gl", 1, "depth of field"), ("gl", 1, "exposure"), ("gl", 1, "vignetting, PRNU"))


def _scene(size, spp: int, adds: str):
    scene = bulge_scene(size=tuple(size), steps=1).replace(render={"samples_per_pixel": spp})
    if adds in ("lighting", "depth of field"):
        effects = demo_effects(scene)
        return scene.replace(lighting=effects.lighting) if adds == "lighting" else scene.replace(optics=effects.optics)
    if adds == "exposure":
        return scene.replace(exposure=EXPOSURE)
    if adds == "mode fast":
        return scene.replace(render={"samples_per_pixel": spp, "mode": "fast"})
    return scene.replace(**CAMERA_EFFECTS) if adds != "—" else scene


def bench(size=FULL_SIZE, reps: int = 3, log=print) -> dict:
    """One row per (backend, samples per pixel, additions) of ROWS."""
    from glsim.bench.report import gl_info, machine_info

    report = {"size": list(size), "date": time.strftime("%Y-%m-%d"), "reps": reps, "rows": []}
    for backend, spp, adds in ROWS:
        with Renderer(_scene(size, spp, adds), backend) as r:
            if backend == "gl":
                report["machine"] = machine_info(gl_info(r))
            J = r.render(0, 1, jacobian=True).jacobian
            plain, with_jac = [], []
            for _ in range(reps):
                t0 = time.perf_counter()
                r.render(0, 1)
                t1 = time.perf_counter()
                r.render(0, 1, jacobian=True)
                plain.append(t1 - t0)
                with_jac.append(time.perf_counter() - t1)
            render, jac = statistics.median(plain), statistics.median(with_jac)
            dofs = 3 * r.mesh.n_nodes
            report["rows"].append({"backend": backend, "spp": spp, "adds": adds, "dofs": dofs, "nnz": int(J.nnz),
                                   "render": render, "jacobian": jac, "fd_estimate": 2 * dofs * render})
            log(f"jacobian: {backend} {spp} spp {adds}: {render:.3g} s render, {jac:.3g} s with the Jacobian")
    return report


def table(report: dict) -> str:
    """The rows as a markdown table (the bench's file and docs/jacobian.md's generated region)."""
    out = ["| backend | spp | with | displacement components | non-zeros | render (s) | render + Jacobian (s) | "
           "Jacobian / render | finite differences (s, est.) | FD / Jacobian |", "|---|---|---|---|---|---|---|---|---|---|"]
    out += [f"| {r['backend']} | {r['spp']} | {r.get('adds', '—')} | {r['dofs']} | {r['nnz']:,} | {r['render']:.3g} | "
            f"{r['jacobian']:.3g} | {r['jacobian'] / r['render']:.1f}× | {r['fd_estimate']:.3g} | "
            f"{r['fd_estimate'] / r['jacobian']:.0f}× |" for r in report["rows"]]
    return "\n".join(out)


def caption(report: dict) -> str:
    from glsim.bench.report import machine_line

    W, H = report["size"]
    return (f"The bulge, camera 0, step 1, exact mode, bspline3, {W}×{H} px; {report['date']}; "
            f"{machine_line(report['machine'])}. Medians of {report['reps']} interleaved renders after a warm-up. "
            "*Render + Jacobian* is `render(..., jacobian=True)` (the image, the samples' float64 raster and the "
            "derivatives in numpy); *with*: mode fast (render and Jacobian), the demo's spotlight or depth of field "
            "(`glsim.scene.demo_effects`), a 2-sample exposure "
            "of a rigid motion, or natural vignetting and 1 % PRNU; finite differences are estimated as 2 · 3N plain "
            "renders (not run).")


def markdown(report: dict) -> str:
    return "# Image Jacobian: time against one render and finite differences\n\n" + caption(report) + "\n\n" + \
        table(report) + "\n"


def write(report: dict, out) -> str:
    """jacobian.json and jacobian.md into ``out``; returns the markdown."""
    from glsim.bench.report import write_results
    return write_results(report, markdown(report), out, "jacobian")
