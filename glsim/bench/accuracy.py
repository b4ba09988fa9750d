"""`glsim bench accuracy`: time and accuracy of every render mode against the float64 CPU oracle.

Scene: ``bulge_scene(size, steps=1)``, camera 0 at load step 1 (deformed). The reference is
the CPU backend in mode ``exact`` (float64 ray/bilinear-patch intersection): its 1-spp
``truth.ref_uv`` is the exact pixel → reference-image mapping, and its image with the same
interpolation and samples per pixel is the grey reference of every row.

Per row: time per image (median of ``Result.seconds`` over timed renders after one warm-up:
geometry + rasterisation + read-back, without scene/mesh/reference/texture setup or truth
maps), mapping error |ref_uv − ref_uv_exact| (px, pixel centres, 1 spp, per backend × mode ×
precision) and grey error |image − reference image| × 255 (8-bit grey levels). A peer section
times riley-raster (PyPI ``riley-raster``) against glsim on the same quad4 plate when installed.

Writes ``accuracy.json`` and ``accuracy.md`` to ``--out`` and prints the markdown table.
"""
from __future__ import annotations

import dataclasses
import datetime
import math
import statistics
import sys
import time
from dataclasses import dataclass
from functools import partial

import numpy as np

from glsim.backends import cpu as oracle
from glsim.scene import speckle
from glsim.bench.formatting import num
from glsim.bench.report import machine_info
from glsim.render import Renderer, Result
from glsim.scene import INTERPOLATIONS, MODES, Plate, Scene, Specimen, Speckle, bulge_scene, stereo_rig

FULL_SIZE = (1624, 1234)
QUICK_SIZE = (406, 308)
CAMERA, STEP = 0, 1
EDGE_PX = 0.01          # mapping error (px) above which a pixel is counted (silhouettes, edges)
CPU_REPS = 3            # the CPU oracle takes seconds per image
SLOW_S = 2.0            # rows whose warm-up render takes longer (s) get at most SLOW_REPS timed renders
SLOW_REPS = 3
SAMPLE_CHUNK = 1 << 22  # reference-image samples interpolated at once (bounds memory)
TARGET_MAP_MAX_PX = 2e-4
TARGET_FAST_S = 0.1
PLATE_ELEMENTS = (50, 40)
PLATE_FILL = 0.7        # fraction of the image area the peer plate covers
PLATE_TEXTURE_PX = 2048


@dataclass(frozen=True)
class Combo:
    """One table row: backend × mode × interpolation × samples per pixel × GL precision × how
    the exact mode places sub-samples (``render.subsamples``)."""
    backend: str
    mode: str
    interpolation: str
    spp: int
    precision: str = "fp64"
    subsamples: str = "mapped"

    def options(self) -> dict:
        """Keyword options of :meth:`Renderer.render`."""
        return {"mode": self.mode, "interpolation": self.interpolation,
                "samples_per_pixel": self.spp, "precision": self.precision, "subsamples": self.subsamples}


def combinations(quick: bool) -> list[Combo]:
    """The rows: GL every mode × interpolation × spp (+ exact and q4 fp32, + exact with
    Newton-placed sub-samples at spp > 1); CPU a few at 1 spp."""
    interps = ("linear", "bspline3") if quick else INTERPOLATIONS
    spps = (1, 4) if quick else (1, 4, 16)
    gl = [Combo("gl", m, i, s) for m in MODES for i in interps for s in spps]
    gl += [Combo("gl", m, i, s, "fp32") for m in ("q4", "exact") for i in interps for s in spps]
    gl += [Combo("gl", "exact", i, s, "fp64", "newton") for i in interps for s in spps if s > 1]
    cpu_interps = ("linear",) if quick else ("linear", "bspline3")
    return gl + [Combo("cpu", m, i, 1) for m in MODES for i in cpu_interps]


# ---- machine ---------------------------------------------------------------------------------


# ---- rendering -------------------------------------------------------------------------------
def render(renderer: Renderer, combo: Combo, truth: bool = False, step: int = STEP) -> Result:
    """Render camera 0 at ``step`` with ``combo``'s options."""
    return renderer.render(CAMERA, step, truth=truth, **combo.options())


def timed(call, reps: int) -> tuple[list[float], Result | Timing]:
    """One warm-up, then ``reps`` timed calls (at most SLOW_REPS if the warm-up took > SLOW_S)."""
    warm = call()
    n = reps if warm.seconds <= SLOW_S else min(reps, SLOW_REPS)
    results = [call() for _ in range(n)]
    return [r.seconds for r in results], results[-1]


def effective_precision(renderer: Renderer, combo: Combo) -> str:
    """The arithmetic actually used: CPU float64; GL fast fp32; GL fp64 only with the extension."""
    if combo.backend == "cpu":
        return "fp64"
    fp64 = combo.precision == "fp64" and combo.mode != "fast" and renderer.backend.fp64
    return "fp64" if fp64 else "fp32"


def reference_images(renderer: Renderer, spps, interps) -> dict[tuple[str, int], np.ndarray]:
    """CPU exact images per (interpolation, spp), as ``oracle.render_view`` makes them but
    rasterised once per spp and sampled in chunks (bounded memory at 16 spp). Always includes
    "procedural": the speckle model itself, the grey truth."""
    view = renderer.view(CAMERA, STEP)
    W, H = view.camera.size
    images = {}
    for spp in sorted(set(spps)):
        s = math.isqrt(spp)
        r = oracle.rasterize(view, "exact", s)
        hit = np.flatnonzero(r["element"] >= 0)
        uv = r["ref_uv"][hit]
        del r
        for method in sorted(set(interps) | {"procedural"}):
            sample = renderer.backend.sampler(method)
            grey = np.full(H * s * W * s, float(renderer.scene.render.background))
            for k in range(0, len(hit), SAMPLE_CHUNK):
                grey[hit[k:k + SAMPLE_CHUNK]] = sample(uv[k:k + SAMPLE_CHUNK])
            images[method, spp] = grey.reshape(H, s, W, s).mean(axis=(1, 3)).astype(np.float32)
    return images


# ---- errors ----------------------------------------------------------------------------------
def mapping_error(truth, exact) -> tuple[dict, np.ndarray]:
    """|ref_uv − ref_uv_exact| (px) over pixels covered in both, coverage differences counted;
    and the (H, W) mask of the pixels covered in both."""
    both = truth.mask & exact.mask
    d = np.linalg.norm(truth.ref_uv[both] - exact.ref_uv[both], axis=-1)
    return {"map_rms_px": float(np.sqrt(np.mean(d * d))), "map_max_px": float(d.max()),
            "map_n_over": int(np.count_nonzero(d > EDGE_PX)),
            "only_here": int(np.count_nonzero(truth.mask & ~exact.mask)),
            "only_exact": int(np.count_nonzero(exact.mask & ~truth.mask))}, both


def grey_error(image: np.ndarray, reference: np.ndarray, both: np.ndarray, name: str = "grey") -> dict:
    """|image − reference| × 255 (8-bit grey levels) over pixels covered in both."""
    d = np.abs(image[both].astype(np.float64) - reference[both]) * 255.0
    return {f"{name}_rms": float(np.sqrt(np.mean(d * d))), f"{name}_max": float(d.max())}


# ---- the accuracy table ------------------------------------------------------------------------
def row(renderer: Renderer, combo: Combo, reps: int, mapping: tuple[dict, np.ndarray],
        references: dict) -> dict:
    """Time one combination and compare its image with the CPU exact one."""
    seconds, last = timed(lambda: render(renderer, combo), reps)
    errors, both = mapping
    return {**dataclasses.asdict(combo), "arithmetic": effective_precision(renderer, combo),
            "reps": len(seconds), "seconds": statistics.median(seconds), "seconds_all": seconds,
            **errors, **grey_error(last.image, references[combo.interpolation, combo.spp], both),
            **grey_error(last.image, references["procedural", combo.spp], both, "speckle")}


def backend_rows(renderer: Renderer, combos: list[Combo], reps: int, exact, references) -> list[dict]:
    """All rows of one backend; one truth render per mode × precision gives their mapping error."""
    mappings: dict[tuple, tuple] = {}
    rows = []
    for combo in combos:
        key = combo.mode, effective_precision(renderer, combo)
        if key not in mappings:
            truth = render(renderer, dataclasses.replace(combo, spp=1), truth=True).truth
            mappings[key] = mapping_error(truth, exact)
        rows.append(row(renderer, combo, reps, mappings[key], references))
        print(f"  {_label(rows[-1])}: {rows[-1]['seconds']:.3g} s", file=sys.stderr, flush=True)
    return rows


def accuracy(size: tuple[int, int], reps: int, quick: bool) -> dict:
    """Every row of the accuracy table, the machine, and the peer comparison."""
    from glsim.backends.gl.context import info

    scene = bulge_scene(size=size, steps=1)
    combos = combinations(quick)
    t0 = time.perf_counter()
    with Renderer(scene, "cpu") as cpu:
        exact = render(cpu, Combo("cpu", "exact", scene.render.interpolation, 1), truth=True).truth
        references = reference_images(cpu, {c.spp for c in combos}, {c.interpolation for c in combos})
        print(f"CPU exact reference images: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        rows = backend_rows(cpu, [c for c in combos if c.backend == "cpu"], min(reps, CPU_REPS), exact, references)
    with Renderer(scene, "gl") as gl:
        machine = machine_info(info(gl.backend.ctx))
        rows = backend_rows(gl, [c for c in combos if c.backend == "gl"], reps, exact, references) + rows
    return {"machine": machine, "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "size": list(size), "scene": f"bulge_scene(size={tuple(size)}, steps=1), camera {CAMERA}, step {STEP}",
            "reps": reps, "records": rows, "peer": peer(size, reps)}


# ---- peer: riley-raster on a quad4 plate -------------------------------------------------------
@dataclass(frozen=True)
class Timing:
    """One timed peer render: wall seconds (perf_counter) and its image."""
    seconds: float
    image: np.ndarray


def plate_geometry(size: tuple[int, int]) -> dict:
    """A 50×40-element plate (mm) covering PLATE_FILL of the image, 600 mm in front of camera 0."""
    fx = stereo_rig(size=size, fx=6818.0 * size[0] / 1624)[0].fx
    nx, ny = PLATE_ELEMENTS
    h_px = math.sqrt(PLATE_FILL * size[0] * size[1] * ny / nx)
    distance = 600.0
    return {"width": h_px * nx / ny * distance / fx, "height": h_px * distance / fx,
            "distance": distance, "fx": fx, "width_px": h_px * nx / ny}


def glsim_plate(size: tuple[int, int], reps: int) -> list[dict]:
    """glsim GL on the plate: q4 and exact (fp64), cubic, 4 spp: the settings closest to riley's."""
    g = plate_geometry(size)
    plate = Plate(width=g["width"], height=g["height"], nx=PLATE_ELEMENTS[0], ny=PLATE_ELEMENTS[1])
    scene = Scene(cameras=stereo_rig(size=size, fx=g["fx"]),
                  specimen=Specimen(plate=plate, t=(0.0, 0.0, g["distance"])),
                  speckle=Speckle(mm_per_px=g["width"] / PLATE_TEXTURE_PX))
    rows = []
    with Renderer(scene, "gl") as gl:
        for combo in (Combo("gl", "q4", "cubic", 4), Combo("gl", "exact", "cubic", 4)):
            seconds, last = timed(lambda: render(gl, combo, step=0), reps)
            rows.append({"name": f"glsim GL {combo.mode} {effective_precision(gl, combo)}", "status": "ok",
                         "reps": len(seconds),
                         "seconds": statistics.median(seconds),
                         "coverage": float(np.mean(last.image != scene.render.background)),
                         "texture": list(gl.reference.image.shape[::-1])})
    return rows


def riley_setup(size: tuple[int, int], nx: int, ny: int, sub_sample: int, k1: float = 0.0):
    """riley-raster's (mesh, camera, config) for the peer plate of :func:`plate_geometry`, meshed
    nx × ny quad4: 2048² speckle texture (5 camera-px dots), Catmull–Rom cubic, ``sub_sample``²
    samples per pixel, radial k1 (OpenCV's) when non-zero."""
    import riley

    g = plate_geometry(size)
    x, y = np.meshgrid(np.linspace(-g["width"] / 2, g["width"] / 2, nx + 1),
                       np.linspace(-g["height"] / 2, g["height"] / 2, ny + 1))
    coords = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    n0 = (np.arange(ny)[:, None] * (nx + 1) + np.arange(nx)[None]).ravel()
    connect = np.stack([n0, n0 + 1, n0 + nx + 2, n0 + nx + 1], 1).astype(np.int64)
    uvs = np.stack([x.ravel() / g["width"] + 0.5, y.ravel() / g["height"] + 0.5], 1)
    dot = 5.0 * PLATE_TEXTURE_PX / g["width_px"]  # 5 camera px speckles, like glsim's default
    texture = np.rint(speckle.generate((PLATE_TEXTURE_PX,) * 2, dot, seed=0) * 255).astype(np.uint8)
    shader = riley.TextureShader(uvs=uvs, texture=texture[None], sample=riley.TextureSample.cubic_catmull_rom)
    convention = riley.ConnectConvention(riley.EElemType.QUAD4, riley.EConnectAxis.ROW, 0, riley.ENodeOrder.RILEY)
    mesh = riley.create_mesh(convention, riley.MeshType.quad4, coords, connect, shader)
    pixel = 3.45e-3  # mm; only fx = focal / pixel matters
    distortion = dict(distort_model=1, distort_k1=k1) if k1 else {}
    camera = riley.Camera(pixels_num=tuple(size), pixels_size=(pixel, pixel), pos_world=(0.0, 0.0, g["distance"]),
                          rot_world=(0.0, 0.0, 0.0), roi_cent_world=(0.0, 0.0, 0.0),
                          focal_length=g["fx"] * pixel, sub_sample=sub_sample, **distortion)
    config = riley.RasterConfig(save_strategy=riley.SaveStrategy.memory, report=riley.ReportMode.off,
                                save_scaling=riley.ScaleStrategy.none)
    return mesh, camera, config


def riley_plate(size: tuple[int, int], reps: int) -> dict:
    """riley-raster on the same plate: quad4, 2048² speckle texture, Catmull–Rom cubic, 4 spp."""
    import riley
    from importlib.metadata import version

    mesh, camera, config = riley_setup(size, *PLATE_ELEMENTS, sub_sample=2)

    def call() -> Timing:
        t0 = time.perf_counter()
        image = riley.raster(mesh, camera, config)
        return Timing(time.perf_counter() - t0, np.squeeze(image))

    seconds, last = timed(call, reps)
    return {"name": f"riley-raster {version('riley-raster')}", "status": "ok", "reps": len(seconds),
            "seconds": statistics.median(seconds), "coverage": float(np.mean(last.image != 0.0)),
            "texture": [PLATE_TEXTURE_PX, PLATE_TEXTURE_PX]}


def peer(size: tuple[int, int], reps: int) -> list[dict]:
    """riley-raster and glsim on the same plate; glsim rows carry the time ratio glsim / riley."""
    try:
        riley_row = riley_plate(size, reps)
    except ImportError:
        riley_row = {"name": "riley-raster", "status": "not installed", "seconds": None}
    except Exception as exc:  # a peer failure must not cost the accuracy table
        riley_row = {"name": "riley-raster", "status": f"failed: {exc}", "seconds": None}
    rows = glsim_plate(size, reps)
    for r in rows:
        r["ratio"] = r["seconds"] / riley_row["seconds"] if riley_row["seconds"] else None
    return [riley_row] + rows


# ---- report ------------------------------------------------------------------------------------
def targets(report: dict) -> list[dict]:
    """The two headline targets, evaluated on this run's rows."""
    recs = [r for r in report["records"] if r["backend"] == "gl"]
    exact_rows = [r for r in recs if r["mode"] == "exact" and r["precision"] == "fp64"]
    exact = max(r["map_max_px"] for r in exact_rows)
    fast = {r["interpolation"]: r["seconds"] for r in recs if r["mode"] == "fast" and r["spp"] == 1}
    W, H = report["size"]
    scale = "" if (W, H) == FULL_SIZE else f" (measured at {W}×{H}; the target is for 1624×1234)"
    return [
        {"target": f"GL exact (fp64) mapping error max ≤ {TARGET_MAP_MAX_PX:g} px",
         "measured": f"{exact:.3g} px ({exact_rows[0]['arithmetic']} shader arithmetic)",
         "met": exact <= TARGET_MAP_MAX_PX},
        {"target": f"GL fast 1 spp < {TARGET_FAST_S:g} s per 1624×1234 image",
         "measured": ", ".join(f"{i} {s:.3g} s" for i, s in fast.items()) + scale,
         "met": None if (W, H) != FULL_SIZE else all(s < TARGET_FAST_S for s in fast.values()),
         "met_by": [i for i, s in fast.items() if s < TARGET_FAST_S]},
    ]


def _met(t: dict) -> str:
    """yes / no / not measured at full size, or which interpolations meet a per-interpolation target."""
    if t["met"] is None:
        return "not measured at 1624×1234"
    if t["met"] or not t.get("met_by"):
        return "yes" if t["met"] else "no"
    return f"with {', '.join(t['met_by'])} only"


def _mode(r: dict) -> str:
    """The mode, and "(newton)" for rows with Newton-placed sub-samples."""
    return r["mode"] + (" (newton)" if r.get("subsamples") == "newton" else "")


def _label(r: dict) -> str:
    return f"{r['backend']} {_mode(r)} {r['arithmetic']} {r['interpolation']} {r['spp']} spp"


_g = partial(num, missing="—")          # a table cell: a figure, or "—" where the run has none


COLUMNS = ("| backend | mode | arith. | interp | spp | reps | time (s) | min–max (s) | map RMS (px) "
           "| map max (px) | > 0.01 px | only here | only exact | grey RMS | grey max | vs speckle RMS | vs speckle max |")

LEGEND = """\
Columns. **arith.**: floating point of the mapping arithmetic actually used (GL fast is always
fp32; GL q4/exact follow the `precision` option, default fp64; CPU is numpy float64).
**time**: median of `Result.seconds` over **reps** timed renders after one warm-up render;
`Result.seconds` times `Renderer.render` = geometry (`make_view`) + rasterisation + read-back
of the image, truth maps off; scene, mesh, reference image, textures and shader compilation
are excluded (done before or in the warm-up). GL and peer rows use {reps} timed renders, except
rows whose warm-up took > {slow} s, which use {slow_reps} to keep the run short; CPU rows use {cpu}.
**min–max**: the fastest and slowest timed render; a wide range means other work shared the CPU.
**map RMS / max**: |ref_uv − ref_uv_exact| in reference-image px (the generated reference has
2 px per camera px at the specimen) over the pixels covered in both (pixel centres, 1 spp,
truth=True, rendered apart from the timing runs); it depends on backend × mode × arithmetic
only, so it repeats across interpolations and spp. **> 0.01 px**: how many of those pixels have
a mapping error above 0.01 px. **only here / only exact**: pixels whose centre is covered by
this row's render but not by the CPU exact reference / the other way round. **grey RMS / max**:
|image − CPU exact image with the same interpolation and spp| × 255 (grey levels of an 8-bit
camera) over the pixels covered in both; at spp > 1 this includes silhouette pixels where one
sub-sample is covered differently, which moves the pixel by up to 0.9 × 255 / spp. The
reference is the CPU backend in mode exact (float64 ray/patch intersection), so its own rows
read 0; its images for every interpolation and spp come from one rasterisation per spp (the
same code path as `glsim.backends.cpu.render_view`). **vs speckle RMS / max**: |image − the exact
speckle| × 255, the reference being the CPU exact mapping with `interpolation = "procedural"`
(the Boolean speckle model evaluated at every sample, no interpolation): the total grey error
of the row, texture interpolation included. **exact (newton)**: `subsamples = "newton"`: a
pixel with one candidate element maps its centre exactly and places its sub-samples by
Gauss-Newton steps from there on their own rays (converged to 1e-7 in ξ, η; pixels the shortcut
cannot decide, e.g. at silhouettes, map every sub-sample); its map columns are the pixel
centres' (those of exact), and its grey columns show where the sub-samples landed.
"""


PEER = """\
## Peer: riley-raster

Same scene for both: a flat {nx}×{ny} quad4 plate covering {fill:.0%} of the {W}×{H} image,
face-on; cubic interpolation (Keys / Catmull–Rom, a = −0.5); 4 samples per pixel (2×2 box).
riley: {tex}² uint8 speckle texture, `riley.raster` into memory, default thread count, wall time
(perf_counter) of that call. glsim: `Result.seconds`, auto-sized reference image.

| renderer | status | reps | time (s) | coverage | texture (px) | glsim / riley |
|---|---|---|---|---|---|---|
"""


def _record_line(r: dict) -> str:
    return (f"| {r['backend']} | {_mode(r)} | {r['arithmetic']} | {r['interpolation']} | {r['spp']} "
            f"| {r['reps']} | {_g(r['seconds'])} | {_g(min(r['seconds_all']))}–{_g(max(r['seconds_all']))} "
            f"| {_g(r['map_rms_px'], '.2e')} | {_g(r['map_max_px'], '.2e')} "
            f"| {r['map_n_over']} | {r['only_here']} | {r['only_exact']} | {_g(r['grey_rms'])} "
            f"| {_g(r['grey_max'])} | {_g(r['speckle_rms'])} | {_g(r['speckle_max'])} |")


def _peer_line(p: dict) -> str:
    tex = "×".join(map(str, p.get("texture", []))) or "—"
    return (f"| {p['name']} | {p['status']} | {p.get('reps', '—')} | {_g(p['seconds'])} "
            f"| {_g(p.get('coverage'), '.0%')} | {tex} | {_g(p.get('ratio'), '.2f')} |")


def markdown(report: dict) -> str:
    """The report as markdown: header, accuracy table, legend, peer table, targets."""
    m = report["machine"]
    W, H = report["size"]
    lines = ["# glsim accuracy benchmark", "",
             f"- Machine: `{m['node']}`, {m['cpu']}, {m['cores']} cores, Python {m['python']}",
             f"- GL: {m['gl']['vendor']} / {m['gl']['renderer']} / {m['gl']['version']}",
             f"- Date: {report['date']}; image {W}×{H}; {report['scene']}", "",
             COLUMNS, "|" + "---|" * 17]
    lines += [_record_line(r) for r in report["records"]]
    lines += ["", LEGEND.format(reps=report["reps"], slow=SLOW_S, slow_reps=min(report["reps"], SLOW_REPS),
                                cpu=min(report["reps"], CPU_REPS)),
              PEER.format(nx=PLATE_ELEMENTS[0], ny=PLATE_ELEMENTS[1], fill=PLATE_FILL, W=W, H=H,
                          tex=PLATE_TEXTURE_PX) + "\n".join(_peer_line(p) for p in report["peer"]),
              "", "## Targets", "", "| target | measured | met |", "|---|---|---|"]
    lines += [f"| {t['target']} | {t['measured']} | {_met(t)} |" for t in report["targets"]]
    return "\n".join(lines) + "\n"


