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

import argparse
import dataclasses
import datetime
import json
import math
import os
import platform
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import interp, oracle, speckle
from .errors import GLUnavailableError
from .render import Renderer, Result
from .scene import INTERPOLATIONS, MODES, Plate, Scene, Specimen, Speckle, bulge_scene, stereo_rig

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
    """One table row: backend × mode × interpolation × samples per pixel × GL precision."""
    backend: str
    mode: str
    interpolation: str
    spp: int
    precision: str = "fp64"

    def options(self) -> dict:
        """Keyword options of :meth:`Renderer.render`."""
        return {"mode": self.mode, "interpolation": self.interpolation,
                "samples_per_pixel": self.spp, "precision": self.precision}


def combinations(quick: bool) -> list[Combo]:
    """The rows: GL every mode × interpolation × spp (+ exact fp32); CPU a few at 1 spp."""
    interps = ("linear", "bspline3") if quick else INTERPOLATIONS
    spps = (1, 4) if quick else (1, 4, 16)
    gl = [Combo("gl", m, i, s) for m in MODES for i in interps for s in spps]
    gl += [Combo("gl", "exact", i, s, "fp32") for i in interps for s in spps]
    cpu_interps = ("linear",) if quick else ("linear", "bspline3")
    return gl + [Combo("cpu", m, i, 1) for m in MODES for i in cpu_interps]


# ---- machine ---------------------------------------------------------------------------------
def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (platform.processor() elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_info(gl_info: dict) -> dict:
    """Host name, CPU, core count, Python, and the GL vendor/renderer/version."""
    return {"node": platform.node(), "cpu": cpu_model(), "cores": os.cpu_count(),
            "python": platform.python_version(),
            "gl": {k: gl_info[k] for k in ("vendor", "renderer", "version")}}


# ---- rendering -------------------------------------------------------------------------------
def render(renderer: Renderer, combo: Combo, truth: bool = False, step: int = STEP) -> Result:
    """Render camera 0 at ``step`` with ``combo``'s options."""
    res = renderer.render(CAMERA, step, truth=truth, **combo.options())
    if renderer.backend_name == "gl":
        # Work around GLBackend._downsample releasing the still-bound framebuffer: the next new
        # render target would otherwise rebind the deleted one (GL_INVALID_OPERATION).
        renderer.backend.ctx.detect_framebuffer(0).use()
    return res


def timed(call, reps: int) -> tuple[list[float], Result]:
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
    rasterised once per spp and interpolated in chunks (bounded memory at 16 spp)."""
    view = renderer.view(CAMERA, STEP)
    W, H = view.camera.size
    background = renderer.scene.render.background
    images = {}
    for s in sorted(set(spps)):
        r = oracle.rasterize(view, "exact", math.isqrt(s))
        hit = np.flatnonzero(r["element"] >= 0)
        uv = r["ref_uv"][hit]
        del r
        for method in interps:
            coeffs = interp.prepare(renderer.reference.image, method, np.float64)
            grey = np.full((H * math.isqrt(s)) * (W * math.isqrt(s)), float(background))
            for k in range(0, len(hit), SAMPLE_CHUNK):
                grey[hit[k:k + SAMPLE_CHUNK]] = interp.sample(coeffs, uv[k:k + SAMPLE_CHUNK], method)
            q = math.isqrt(s)
            images[method, s] = grey.reshape(H, q, W, q).mean(axis=(1, 3)).astype(np.float32)
    return images


# ---- errors ----------------------------------------------------------------------------------
def mapping_error(truth, exact) -> dict:
    """|ref_uv − ref_uv_exact| (px) over pixels covered in both; coverage differences counted."""
    both = truth.mask & exact.mask
    d = np.linalg.norm(truth.ref_uv[both] - exact.ref_uv[both], axis=-1)
    return {"map_rms_px": float(np.sqrt(np.mean(d * d))), "map_max_px": float(d.max()),
            "map_n_over": int(np.count_nonzero(d > EDGE_PX)),
            "only_here": int(np.count_nonzero(truth.mask & ~exact.mask)),
            "only_exact": int(np.count_nonzero(exact.mask & ~truth.mask)), "both": both}


def grey_error(image: np.ndarray, reference: np.ndarray, both: np.ndarray) -> dict:
    """|image − reference| × 255 (8-bit grey levels) over pixels covered in both."""
    d = np.abs(image[both].astype(np.float64) - reference[both]) * 255.0
    return {"grey_rms": float(np.sqrt(np.mean(d * d))), "grey_max": float(d.max())}


# ---- the accuracy table ------------------------------------------------------------------------
def row(renderer: Renderer, combo: Combo, reps: int, mapping: dict, references: dict) -> dict:
    """Time one combination and compare its image with the CPU exact one."""
    seconds, last = timed(lambda: render(renderer, combo), reps)
    errors = {k: v for k, v in mapping.items() if k != "both"}
    return {**dataclasses.asdict(combo), "precision": effective_precision(renderer, combo),
            "reps": len(seconds), "seconds": statistics.median(seconds), "seconds_all": seconds,
            **errors, **grey_error(last.image, references[combo.interpolation, combo.spp], mapping["both"])}


def mapping_key(renderer: Renderer, combo: Combo) -> tuple:
    return combo.backend, combo.mode, effective_precision(renderer, combo)


def backend_rows(renderer: Renderer, combos: list[Combo], reps: int, exact, references) -> list[dict]:
    """All rows of one backend; one truth render per mode × precision gives their mapping error."""
    mappings: dict[tuple, dict] = {}
    rows = []
    for combo in combos:
        key = mapping_key(renderer, combo)
        if key not in mappings:
            truth = render(renderer, dataclasses.replace(combo, spp=1), truth=True).truth
            mappings[key] = mapping_error(truth, exact)
        rows.append(row(renderer, combo, reps, mappings[key], references))
        print(f"  {_label(rows[-1])}: {rows[-1]['seconds']:.3g} s", file=sys.stderr, flush=True)
    return rows


def accuracy(size: tuple[int, int], reps: int, quick: bool) -> dict:
    """Every row of the accuracy table, the machine, and the peer comparison."""
    from .gl.context import info

    scene = bulge_scene(size=size, steps=1)
    combos = combinations(quick)
    with Renderer(scene, "cpu") as cpu:
        exact = render(cpu, Combo("cpu", "exact", scene.render.interpolation, 1), truth=True).truth
        references = reference_images(cpu, {c.spp for c in combos}, {c.interpolation for c in combos})
        print("reference done", file=sys.stderr, flush=True)
        rows = backend_rows(cpu, [c for c in combos if c.backend == "cpu"], min(reps, CPU_REPS), exact, references)
    with Renderer(scene, "gl") as gl:
        machine = machine_info(info(gl.backend.ctx))
        rows = backend_rows(gl, [c for c in combos if c.backend == "gl"], reps, exact, references) + rows
    return {"machine": machine, "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "size": list(size), "scene": f"bulge_scene(size={tuple(size)}, steps=1), camera {CAMERA}, step {STEP}",
            "reps": reps, "records": rows, "peer": peer(size, reps)}


# ---- peer: riley-raster on a quad4 plate -------------------------------------------------------
def plate_geometry(size: tuple[int, int]) -> dict:
    """A 50×40-element plate (mm) covering PLATE_FILL of the image, 600 mm in front of camera 0."""
    cam = stereo_rig(size=size, fx=6818.0 * size[0] / 1624)[0]
    nx, ny = PLATE_ELEMENTS
    h_px = math.sqrt(PLATE_FILL * size[0] * size[1] * ny / nx)
    distance = 600.0
    return {"width": h_px * nx / ny * distance / cam.fx, "height": h_px * distance / cam.fx,
            "distance": distance, "fx": cam.fx}


def glsim_plate(size: tuple[int, int], reps: int) -> list[dict]:
    """glsim GL on the plate: q4 and exact, cubic, 4 spp (the settings closest to riley's)."""
    g = plate_geometry(size)
    scene = Scene(cameras=stereo_rig(size=size, fx=g["fx"]),
                  specimen=Specimen(plate=Plate(width=g["width"], height=g["height"],
                                                nx=PLATE_ELEMENTS[0], ny=PLATE_ELEMENTS[1]),
                                    t=(0.0, 0.0, g["distance"])),
                  speckle=Speckle(mm_per_px=g["width"] / PLATE_TEXTURE_PX))
    rows = []
    with Renderer(scene, "gl") as gl:
        for mode in ("q4", "exact"):
            combo = Combo("gl", mode, "cubic", 4)
            seconds, last = timed(lambda: render(gl, combo, step=0), reps)
            rows.append({"name": f"glsim GL {mode} fp64", "interpolation": "cubic (Keys a=−0.5)", "spp": 4,
                         "reps": len(seconds), "seconds": statistics.median(seconds),
                         "coverage": float(np.mean(last.image != scene.render.background)),
                         "texture": list(gl.reference.image.shape[::-1])})
    return rows
