"""`glsim bench effects`: what each optical effect costs per image, and how closely each GL
depth-of-field scheme follows the oracle's exact 2-D gather.

The bulge stereo pair (both cameras, step 1) at 1624×1234 by default, rendered with no effect,
each effect alone (lighting, depth of field, noise: ``demo_effects``) and all together, with the
GL and the CPU backend. Per row: median seconds per image (``Result.seconds``: geometry +
passes + read-back) over timed renders after one warm-up, the increment over the effect-free
row and its share of the all-effects row.

Motion (``motion`` rows, docs/motion.md): the same pair with ``[exposure]`` alone (4 samples
over 0.2 s around step 1, the state interpolated between steps 0 and 1), with a rolling
shutter alone (``line_time`` 10 µs, a rigid 100 mm/s along x: each row rendered on its own) and
with a rolling shutter and a Gaussian PSF (σ 0.5 px: each row rendered in a band of 5), GL and
CPU, each against the still pair timed in the same run, with their max |GL − oracle|.

Camera (``camera`` rows, docs/camera.md): the same pair with each of a Gaussian and an Airy lens
PSF, vignetting, a fill factor of 0.5 (at 4 samples per pixel) and fixed-pattern noise alone, GL
and CPU, each against the same render without it, with their max |GL − oracle|;
``glsim bench effects --only camera`` (or ``--only motion``) runs those rows alone and merges them
into the results there.

Depth of field (``dof`` rows): every GL scheme (``optics.scheme``: separable, hybrid, gather,
expansion; the disk kernel's 2-D gather) on the bulge pair (depth of field only) and on the
four scenes of :func:`dof_scenes` — a tilted plate whose outline lies in the blurred region, a
plate with a hole, two plates at different depths, a plate that the in-focus threshold crosses —
against the CPU oracle at every covered pixel: mean and max |GL − oracle| (fraction of full
scale), the pixels beyond 2e-3 (half a grey level of 8 bit) and the GL time per image.
"""
from __future__ import annotations

import dataclasses
import datetime
import json
import statistics
import sys
from pathlib import Path

import numpy as np

from glsim.bench.formatting import sig
from glsim.io import images as io
from glsim.render import Renderer
from glsim.scene import Optics, Plate, Render, Scene, Specimen, bulge_scene, demo_effects
from glsim.scene import mesh as meshmod
from glsim.scene.camera import Camera

VARIANTS = ("none", "lighting", "optics", "noise", "all")
CPU_REPS = 2
SCHEMES = ("separable", "hybrid", "gather", "expansion")   # GL's Gaussian; the disk is always gathered
DOF_GOAL = 2e-3             # of full scale: half a grey level of 8 bit
DOF_WIDTH = 640             # the dof_scenes' width in the full-size run (at most the bench width)


# ---- depth-of-field scenes -----------------------------------------------------------------
def _rotation(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])}[axis]


def _plate(w, h, nx, ny, R=np.eye(3), t=(0.0, 0.0, 300.0), hole=None):
    """Nodes (placed) and quads of a w × h mm plate, less the elements inside a centred hole (w, h)."""
    m = meshmod.plate(w, h, nx, ny)
    quads = np.asarray(m.quads)
    if hole is not None:
        c = np.asarray(m.nodes)[quads].mean(axis=1)
        quads = quads[~((np.abs(c[:, 0]) < hole[0] / 2) & (np.abs(c[:, 1]) < hole[1] / 2))]
    return np.asarray(m.nodes) @ R.T + np.asarray(t, float), quads


def _mesh(*parts) -> meshmod.Mesh:
    nodes, quads, offset = [], [], 0
    for n, q in parts:
        nodes.append(n)
        quads.append(q + offset)
        offset += len(n)
    nodes, quads = np.concatenate(nodes), np.concatenate(quads)
    return meshmod.Mesh(nodes, quads, np.arange(1, len(nodes) + 1), np.arange(1, len(quads) + 1))


def dof_scenes(width: int = 160) -> dict[str, tuple[Scene, meshmod.Mesh]]:
    """The hard depth-of-field scenes, one camera (width × 3/4 width px, the plates ~300 mm away,
    a 50 mm lens whose pixel pitch matches the camera), Gaussian kernel; each a scene and the
    mesh to render it with (``Renderer(scene, mesh=mesh)``):

    - ``outline``: a 40 × 30 mm plate turned 40° about y, focused 340 mm away at f/4: blurred
      everywhere (σ 1.4–2.9 px), its outline against the background;
    - ``hole``: a plate with a 16 × 12 mm hole, turned 15° about x, focused at 260 mm, f/2.8
      (σ 3.6–4.3 px): the background seen through the hole;
    - ``steps``: two plates at 280 and 330 mm, the nearer hiding part of the farther, focused at
      300 mm, f/2.8 (σ 1.9 and 2.3 px): a depth step between parts;
    - ``threshold``: a plate turned 50° about y focused at its centre, f/2.8, ``coc_px`` 1.5:
      the CoC crosses ``coc_px`` on two lines across it (σ jumps from 0 to 0.75 px).
    """
    W, H = width, width * 3 // 4
    fx = 4.5 * W
    cam = Camera(name="cam0", size=(W, H), fx=fx, fy=fx, cx=(W - 1) / 2, cy=(H - 1) / 2)

    def optics(D, N, coc=1.0):
        return Optics(focal_length=50.0, f_number=N, focus_distance=D, pixel_pitch=50.0 / fx, coc_px=coc)

    cases = {"outline": (_mesh(_plate(40, 30, 8, 6, _rotation("y", 40))), optics(340.0, 4.0)),
             "hole": (_mesh(_plate(40, 30, 10, 10, _rotation("x", 15), hole=(16, 12))), optics(260.0, 2.8)),
             "steps": (_mesh(_plate(24, 20, 6, 5, t=(-8.0, 0.0, 280.0)), _plate(30, 24, 6, 6, t=(6.0, 3.0, 330.0))),
                       optics(300.0, 2.8)),
             "threshold": (_mesh(_plate(40, 30, 8, 6, _rotation("y", 50))), optics(300.0, 2.8, 1.5))}
    return {name: (Scene(cameras=(cam,), specimen=Specimen(plate=Plate()), render=Render(interpolation="linear"),
                         optics=opt), mesh) for name, (mesh, opt) in cases.items()}


def dof_variants() -> list[tuple[str, str]]:
    """(kernel, scheme) of every GL depth-of-field row."""
    return [("gaussian", s) for s in SCHEMES] + [("disk", "gather")]


def with_dof(scene: Scene, kernel: str, scheme: str) -> Scene:
    return dataclasses.replace(scene, optics=dataclasses.replace(scene.optics, kernel=kernel, scheme=scheme))


def _blur_sizes(scene: Scene, camera: int, truth) -> np.ndarray:
    """σ (or disk radius, px) at the covered pixels of ``camera``, from the truth's deformed
    points (camera 0's frame) moved into that camera's frame."""
    from glsim.effects.dof import blur_sigma
    from glsim.scene.camera import to_camera

    cam0, cam = scene.cameras[0], scene.cameras[camera]
    X0 = truth.X_deformed[truth.mask]
    world = (X0 - np.asarray(cam0.t, float)) @ np.asarray(cam0.R, float)
    return blur_sigma(to_camera(world, cam)[:, 2], scene.optics)


def dof_rows(base: Scene, reps: int, width: int, ctx) -> list[dict]:
    """The ``dof`` records: every (kernel, scheme) on the bulge pair (``base``: demo_effects,
    depth of field only) and on :func:`dof_scenes` at ``width``. Per scene the variants' timed
    renders are interleaved (rep by rep), so that a machine whose load changes during the run
    shifts them alike and their time ratios hold."""
    cases = [("bulge", base, None, tuple(range(len(base.cameras))), 1)]
    cases += [(name, scene, mesh, (0,), 0) for name, (scene, mesh) in dof_scenes(width).items()]
    rows = []
    for name, scene, mesh, cams, step in cases:
        oracle = {}
        for kernel in ("gaussian", "disk"):
            with Renderer(with_dof(scene, kernel, "gather"), "cpu", mesh=mesh) as r:
                oracle.update({(kernel, c): r.render(c, step, truth=True) for c in cams})
        renderers = {v: Renderer(with_dof(scene, *v), "gl", ctx=ctx, mesh=mesh) for v in dof_variants()}
        try:
            for r in renderers.values():
                for c in cams:
                    r.render(c, step)  # warm-up: programs, textures, ray maps
            runs = {v: [] for v in renderers}
            for _ in range(reps):
                for v, r in renderers.items():
                    runs[v] += [(c, r.render(c, step)) for c in cams]
        finally:
            for r in renderers.values():
                r.close()
        for (kernel, scheme), done in runs.items():
            last = dict(done[-len(cams):])  # the last render of each camera
            d = np.concatenate([np.abs(last[c].image.astype(np.float64) - oracle[kernel, c].image)[
                oracle[kernel, c].truth.mask] for c in cams])
            sigma = np.concatenate([_blur_sizes(scene, c, oracle[kernel, c].truth) for c in cams])
            rec = {"scene": name, "kernel": kernel, "scheme": scheme, "reps": reps,
                   "blur_px": [float(sigma.min()), float(sigma.max())],
                   "seconds": statistics.median(res.seconds for _, res in done),
                   "seconds_all": [res.seconds for _, res in done],
                   "cpu_seconds": statistics.median(oracle[kernel, c].seconds for c in cams),
                   "stages": list(done[-1][1].stages), "size": list(scene.cameras[0].size),
                   "mean_error": float(d.mean()), "max_error": float(d.max()),
                   "over_goal": int((d > DOF_GOAL).sum()), "pixels": int(d.size)}
            rows.append(rec)
            print(f"  dof {name} {kernel} {scheme}: max {rec['max_error']:.2g}, {rec['seconds']:.3g} s",
                  file=sys.stderr, flush=True)
    return rows


MOTION = {"exposure": {"exposure": {"time": 0.2, "samples": 4}},
          "rolling": {"exposure": {"velocity": [100.0, 0.0, 0.0]}, "sensor": {"line_time": 1e-5}},
          "rolling, PSF": {"exposure": {"velocity": [100.0, 0.0, 0.0]}, "sensor": {"line_time": 1e-5},
                           "psf": {"kind": "gaussian", "sigma": 0.5}}}   # each row a band of 2·2 + 1 rows
MOTION_REPS = 1            # timed renders per camera of a motion row (the rolling shutter renders every row)


def motion_rows(base: Scene, ctx) -> list[dict]:
    """The ``motion`` records: each of MOTION on ``base`` (no other effect), GL and CPU, seconds per
    image (both cameras, step 1; GL after one warm-up), the same for ``base`` itself in the same
    run (``base_seconds``) and the max |GL − oracle| (full scale)."""
    rows, still = [], {}
    for name, sections in {"none": {}, **MOTION}.items():
        scene = base.replace(**sections) if sections else base
        runs = {}
        for backend in ("gl", "cpu"):
            with Renderer(scene, backend, ctx=ctx if backend == "gl" else None) as r:
                if backend == "gl":
                    r.render(0, 1)   # warm-up: programs, textures, ray maps
                runs[backend] = [r.render(c, 1) for _ in range(MOTION_REPS) for c in range(len(scene.cameras))]
        if name == "none":
            still = {b: statistics.median(x.seconds for x in done) for b, done in runs.items()}
            continue
        diff = max(float(np.abs(g.image.astype(np.float64) - c.image).max()) for g, c in zip(runs["gl"], runs["cpu"]))
        for backend, done in runs.items():
            rows.append({"backend": backend, "effects": name, "reps": MOTION_REPS, "settings": sections,
                         "seconds": statistics.median(x.seconds for x in done), "seconds_all": [x.seconds for x in done],
                         "base_seconds": still[backend], "stages": list(done[-1].stages), "max_gl_vs_cpu": diff})
            print(f"  {backend} {name}: {rows[-1]['seconds']:.3g} s", file=sys.stderr, flush=True)
    return rows


PITCH = 0.0055              # mm: the camera-effect rows' Airy disk on 5.5 µm pixels (first zero 0.98 px at f/8)
CAMERA = {"psf gaussian": {"psf": {"kind": "gaussian", "sigma": 1.0}},
          "psf airy": {"psf": {"kind": "airy", "f_number": 8.0, "pixel_pitch": PITCH}},
          "vignetting": {"vignetting": {"natural": True, "radial": [0.1]}},
          "fill factor": {"sensor": {"fill_factor": 0.5}, "render": {"samples_per_pixel": 4}},
          "fixed pattern": {"sensor": {"prnu": 1.0, "dsnu": 2.0}}}
CAMERA_REPS = 1            # timed renders per camera of a camera-effect row and of its own baseline


def camera_rows(base: Scene, ctx) -> list[dict]:
    """The ``camera`` records (docs/camera.md): each of CAMERA on ``base`` (no other effect), GL and
    CPU: seconds per image (both cameras, step 1, after one warm-up) with the effect and without it
    (the same render options; measured in the same call, interleaved), and the max |GL − oracle|
    over both images (full scale)."""
    rows = []
    for name, sections in CAMERA.items():
        scene = base.replace(**sections)
        plain = base.replace(**{k: v for k, v in sections.items() if k == "render"})
        runs, images = {}, {}
        for backend in ("gl", "cpu"):
            c = ctx if backend == "gl" else None
            with Renderer(scene, backend, ctx=c) as r, Renderer(plain, backend, ctx=c) as r0:
                r.render(0, 1), r0.render(0, 1)    # warm-up: programs, kernels, gains
                done = [(r.render(k, 1), r0.render(k, 1)) for _ in range(CAMERA_REPS) for k in range(len(scene.cameras))]
            runs[backend] = done
            images[backend] = [x.image.astype(np.float64) for x, _ in done[-len(scene.cameras):]]
        diff = max(float(np.abs(g - c).max()) for g, c in zip(images["gl"], images["cpu"]))
        for backend, done in runs.items():
            rows.append({"backend": backend, "effects": name, "reps": CAMERA_REPS, "settings": sections,
                         "seconds": statistics.median(x.seconds for x, _ in done),
                         "base_seconds": statistics.median(x.seconds for _, x in done),
                         "seconds_all": [x.seconds for x, _ in done], "stages": list(done[-1][0].stages),
                         "max_gl_vs_cpu": diff})
            print(f"  {backend} {name}: {rows[-1]['seconds']:.3g} s", file=sys.stderr, flush=True)
    return rows


def camera_table(rows: list[dict]) -> str:
    """The camera-effect rows as a markdown table (also docs/camera.md's generated region)."""
    lines = ["| backend | effect | settings | time per image (s) | without it (s) | × without | max GL − oracle |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        settings = "; ".join(f"[{k}] " + ", ".join(f"{n} = {v}" for n, v in t.items()) for k, t in r["settings"].items())
        lines.append(f"| {r['backend']} | {r['effects']} | {settings} | {r['seconds']:.3g} | {r['base_seconds']:.3g} | "
                     f"{r['seconds'] / r['base_seconds']:.3g} | {sig(r['max_gl_vs_cpu'], trailing_zeros=False)} |")
    return "\n".join(lines)


ONLY = ("camera", "motion")   # row groups `glsim bench effects --only` runs alone


def rows_only(kind: str, size: tuple[int, int], previous: dict | None) -> dict:
    """The ``kind`` rows (ONLY) alone at ``size``, merged into ``previous`` (a report of the same
    size, whose other rows are kept) or a report of their own."""
    from glsim.bench.report import machine_info
    from glsim.backends.gl.context import create_context, info

    make = {"camera": camera_rows, "motion": motion_rows}[kind]
    ctx = create_context()
    try:
        machine = machine_info(info(ctx))
        rows = make(bulge_scene(size=size, steps=1), ctx)
    finally:
        ctx.release()
    date = datetime.datetime.now().astimezone().isoformat(timespec="seconds")
    if previous is not None and previous.get("size") == list(size):
        return {**previous, kind: rows, f"{kind}_run": {"machine": machine, "date": date}}
    return {"machine": machine, "date": date, "size": list(size), "records": [],
            "scene": f"bulge_scene(size={tuple(size)}, steps=1), both cameras, step 1", kind: rows}


def motion_table(report: dict) -> str:
    """The motion rows as a markdown table: time per image and over the same run's still image
    (older results without it: over the effect-free record)."""
    none = {r["backend"]: r["seconds"] for r in report["records"] if r["effects"] == "none"}
    lines = ["| backend | motion | settings | time per image (s) | still (s) | × still | max GL − oracle |",
             "|---|---|---|---|---|---|---|"]
    for r in report["motion"]:
        settings = "; ".join(f"[{k}] " + ", ".join(f"{n} = {v}" for n, v in t.items()) for k, t in r["settings"].items())
        base = r.get("base_seconds", none.get(r["backend"]))
        lines.append(f"| {r['backend']} | {r['effects']} | {settings} | {r['seconds']:.3g} | {base:.3g} | "
                     f"{r['seconds'] / base:.3g} | {sig(r['max_gl_vs_cpu'], trailing_zeros=False)} |")
    return "\n".join(lines)


def variant(scene, name: str):
    """``scene`` with the demo's effects: none, one of them, or all."""
    full = demo_effects(scene)
    if name == "all":
        return full
    keep = {e: getattr(full, e) if e == name else None for e in ("lighting", "optics", "noise")}
    return dataclasses.replace(scene, **keep)


def time_variant(scene, backend: str, reps: int, ctx=None) -> dict:
    """Median and all seconds per image over both cameras' renders of step 1."""
    with Renderer(scene, backend, ctx=ctx) as r:
        for cam in range(len(scene.cameras)):
            r.render(cam, 1)  # warm-up: programs, textures, ray maps
        runs = [r.render(cam, 1) for _ in range(reps) for cam in range(len(scene.cameras))]
    return {"seconds": statistics.median(x.seconds for x in runs), "seconds_all": [x.seconds for x in runs],
            "stages": list(runs[-1].stages), "saturated": runs[-1].saturated}


def effects(size: tuple[int, int], reps: int) -> dict:
    from glsim.bench.report import machine_info
    from glsim.backends.gl.context import create_context, info

    base = bulge_scene(size=size, steps=1)
    ctx = create_context()
    try:
        machine = machine_info(info(ctx))
        rows = []
        for backend, n in (("gl", reps), ("cpu", min(reps, CPU_REPS))):
            for name in VARIANTS:
                rec = {"backend": backend, "effects": name, "reps": n,
                       **time_variant(variant(base, name), backend, n, ctx if backend == "gl" else None)}
                rows.append(rec)
                print(f"  {backend} {name}: {rec['seconds']:.3g} s", file=sys.stderr, flush=True)
        dof = dof_rows(variant(base, "optics"), reps, min(DOF_WIDTH, size[0]), ctx)
        moving = motion_rows(base, ctx)
        camera = camera_rows(base, ctx)
    finally:
        ctx.release()
    for r in rows:
        none = next(x for x in rows if x["backend"] == r["backend"] and x["effects"] == "none")["seconds"]
        every = next(x for x in rows if x["backend"] == r["backend"] and x["effects"] == "all")["seconds"]
        r["added_seconds"] = r["seconds"] - none
        r["share_of_all"] = r["added_seconds"] / every
    return {"machine": machine, "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "size": list(size), "scene": f"demo_effects(bulge_scene(size={tuple(size)}, steps=1)), both cameras, step 1",
            "records": rows, "dof_goal": DOF_GOAL, "dof": dof, "motion": moving, "camera": camera}


def markdown(report: dict) -> str:
    m = report["machine"]
    lines = ["# glsim effects benchmark", "",
             f"- Machine: `{m['node']}`, {m['cpu']}, {m['cores']} cores, Python {m['python']}",
             f"- GL: {m['gl']['vendor']} / {m['gl']['renderer']} / {m['gl']['version']}",
             f"- Date: {report['date']}; image {report['size'][0]}×{report['size'][1]}; {report['scene']}",
             "- Effects as `glsim demo --effects`: a spotlight (Table 1 values), 30 mm f/2 depth of field "
             "focused at 600 mm, 2 % Gaussian noise.",
             "- time: median `Result.seconds` per image (both cameras) after one warm-up each; "
             "min–max: the spread of those renders (an increment smaller than it is not resolved); "
             "added: over the no-effect row; share: added / the all-effects row's time.", "",
             "| backend | effects | reps | time per image (s) | min–max (s) | added (s) | share of all | stages run |",
             "|---|---|---|---|---|---|---|---|"]
    for r in report["records"]:
        lines.append(f"| {r['backend']} | {r['effects']} | {r['reps']} | {r['seconds']:.3g} | "
                     f"{min(r['seconds_all']):.3g}–{max(r['seconds_all']):.3g} | "
                     f"{r['added_seconds']:+.3g} | {r['share_of_all']:.0%} | {', '.join(r['stages'])} |")
    if report.get("motion"):
        run = report.get("motion_run", report)
        lines += ["", "## Motion over the exposure and the rolling shutter (docs/motion.md)", "",
                  f"Same scene, no other effect ({run['date']}); time: median `Result.seconds` per image (both "
                  "cameras), GL after one warm-up; still: the same pair without motion, timed in the same run; "
                  "GL − oracle: the largest over both images, absolute, full scale.", "", motion_table(report)]
    if report.get("camera"):
        run = report.get("camera_run", report)
        lines += ["", "## Lens PSF, vignetting, fill factor, fixed-pattern noise (docs/camera.md)", "",
                  f"Same scene, no other effect ({run['date']}); time: median `Result.seconds` per image (both cameras) "
                  "after one warm-up, with the effect and without it in the same call (the fill-factor row and its "
                  "baseline at 4 samples per pixel); GL − oracle: the largest over both images, absolute, full scale.",
                  "", camera_table(report["camera"])]
    if report.get("dof"):
        lines += ["", "## Depth of field: GL schemes against the oracle's exact 2-D gather", "",
                  f"Every covered pixel; error as a fraction of full scale (goal ≤ {report['dof_goal']:g}, half a grey "
                  "level of 8 bit); time: median `Result.seconds` per image of the GL render with depth of field only "
                  "(bulge: both cameras of the benchmark's scene; the other scenes: `glsim.bench.effects."
                  "dof_scenes`), ratio to the separable pair on the same scene; oracle: the CPU render's time.", "",
                  dof_table(report["dof"])]
    return "\n".join(lines) + "\n"


def dof_table(rows: list[dict]) -> str:
    """The depth-of-field rows as a markdown table (also docs/effects.md's generated region)."""
    sep = {r["scene"]: r["seconds"] for r in rows if r["scheme"] == "separable"}
    lines = ["| scene | size | blur (px) | kernel | scheme | mean error | max error | pixels > goal | GL time (s) | "
             "vs separable | oracle (s) | passes |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['size'][0]}×{r['size'][1]} | {r['blur_px'][0]:.2g}–{r['blur_px'][1]:.2g} | "
                     f"{r['kernel']} | {r['scheme']} | {sig(r['mean_error'], trailing_zeros=False)} | "
                     f"{sig(r['max_error'], trailing_zeros=False)} | {r['over_goal']} of {r['pixels']} | "
                     f"{r['seconds']:.3g} | {r['seconds'] / sep[r['scene']]:.2g}× | {r['cpu_seconds']:.3g} | "
                     f"{', '.join(s for s in r['stages'] if s.startswith('blur'))} |")
    return "\n".join(lines)


def write(report: dict, out: Path) -> str:
    text = markdown(report)
    out.mkdir(parents=True, exist_ok=True)
    io.write_text(out / "effects.json", json.dumps(report, indent=2) + "\n")
    io.write_text(out / "effects.md", text)
    return text
