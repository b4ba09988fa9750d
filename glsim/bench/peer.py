"""`glsim bench peer`: glsim GL against riley-raster on one plate, timed interleaved, accuracy measured.

Scene: the accuracy peer plate (:func:`glsim.bench.accuracy.plate_geometry`, 50×40 quad4,
face-on 600 mm in front of camera 0, 70 % of the image), once without distortion and once
with radial k1 = −0.1 (OpenCV's model in both renderers). Every renderer samples its
speckle with Keys / Catmull–Rom cubic at 4 spp (2×2 sub-samples): riley-raster (PyPI
``riley-raster``, default thread count, its own 2048² texture) and glsim GL in modes fast,
q4, exact fp64 and exact fp32, the exact ones also with sub-samples placed by Newton from the
pixel centre (``subsamples = "newton"``; its map columns are the pixel centres', so its grey
columns show the sub-samples).

Time: wall seconds (perf_counter) of one ``riley.raster`` / ``Renderer.render`` call; one
warm-up each, then ``reps`` repetitions that each render once with every renderer and
variant in turn; median and min–max per row.

Accuracy, measured for every row against the float64 CPU oracle (``glsim.backends.cpu``, mode
exact) at 1 spp pixel centres: each renderer's (element, ξ, η) per pixel gives a material
point on the plate (mm), compared with the oracle's; the distance is given in camera px
(× fx / 600 mm, the plate's scale on the optical axis; distortion changes it by < 1 % at the
plate's corners). riley reports ξ and η per pixel (its full_stats xi/eta maps) but no element
index: its element is taken from the oracle's at that pixel, and its η runs opposite to
glsim's (its world y is glsim's −y), so the point is bilinear(element, ξ, −η). Grey error
(8-bit grey levels) over the pixels whose 4 oracle sub-samples all hit the plate: riley's
image against the oracle's sub-sample points sampled with Catmull–Rom on riley's own texture
(texel centres at u·(N−1), row (½ − y/h)·(N−1), taps beyond the edge clamped), glsim's image against the oracle image
rendered with the same settings (cubic, 4 spp, glsim's reference image).

Writes ``peer.json`` and ``peer.md``; only the full run writes to bench/results.
"""
from __future__ import annotations

import contextlib
import dataclasses
import datetime
import math
import os
import statistics
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import numpy as np

from glsim.backends import cpu as oracle
from glsim.bench.accuracy import PLATE_ELEMENTS, PLATE_TEXTURE_PX, TARGET_MAP_MAX_PX, Combo, \
    effective_precision, plate_geometry, riley_setup
from glsim.bench.formatting import num
from glsim.bench.report import gl_info, machine_info, machine_line, write_results
from glsim.bench.scaling import plate_scene
from glsim.render import Renderer
from glsim.scene import bilinear as bl
from glsim.scene import speckle
from glsim.scene.camera import Distortion
from glsim.imaging import interp

FULL_SIZE = (1624, 1234)
QUICK_SIZE = (812, 617)
REPS = 7
K1S = (0.0, -0.1)
SPP = 4
COMBOS = (Combo("gl", "fast", "cubic", SPP), Combo("gl", "q4", "cubic", SPP), Combo("gl", "exact", "cubic", SPP),
          Combo("gl", "exact", "cubic", SPP, "fp32"), Combo("gl", "exact", "cubic", SPP, "fp64", "newton"),
          Combo("gl", "exact", "cubic", SPP, "fp32", "newton"))
EDGE = 2                # texels of edge replication around riley's texture: it clamps its taps there
GOAL_EXACT_RATIO, GOAL_EXACT_STRETCH, GOAL_FAST_RATIO = 1.0, 0.5, 0.5   # glsim / riley time at equal accuracy


def scene(size: tuple[int, int]):
    """The peer plate as one glsim Scene, cubic interpolation: camera i at camera 0's pose with
    radial k1 = K1S[i] (one renderer for every variant: timing interleaves them)."""
    s = plate_scene(size, PLATE_ELEMENTS[0] * PLATE_ELEMENTS[1])
    return dataclasses.replace(s, cameras=tuple(dataclasses.replace(s.cameras[0], name=f"k1_{k1:g}",
                                                                    distortion=Distortion(k1=k1)) for k1 in K1S))


def label(renderer: Renderer, combo: Combo) -> str:
    """The row's name: mode, the arithmetic actually used (fast is always fp32), and "newton" for
    sub-samples placed by Newton from the pixel centre (render.subsamples)."""
    newton = " newton" if combo.subsamples == "newton" else ""
    return f"glsim GL {combo.mode} {effective_precision(renderer, combo)}{newton}"


# ---- riley ---------------------------------------------------------------------------------------
@contextlib.contextmanager
def _quiet():
    """riley's native code prints its full_stats report to file descriptors 1 and 2: send both to /dev/null."""
    import ctypes

    sys.stdout.flush()
    sys.stderr.flush()
    saved, null = [os.dup(1), os.dup(2)], os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    os.dup2(null, 2)
    try:
        yield
    finally:
        ctypes.CDLL(None).fflush(None)                   # C stdio buffers, before the descriptors come back
        for fd, old in enumerate(saved, 1):
            os.dup2(old, fd)
            os.close(old)
        os.close(null)


def riley_texture(size: tuple[int, int]) -> np.ndarray:
    """riley's speckle texture (N×N grey levels 0–255) as :func:`riley_setup` builds it."""
    dot = 5.0 * PLATE_TEXTURE_PX / plate_geometry(size)["width_px"]
    return np.rint(speckle.generate((PLATE_TEXTURE_PX,) * 2, dot, seed=0) * 255)


def riley_coordinates(size: tuple[int, int], k1: float) -> tuple[np.ndarray, np.ndarray]:
    """riley's ξ, η maps (H, W; NaN off the plate) at 1 spp pixel centres, from its full_stats
    report (``diag_cam0_frame0_{xi,eta}.csv``, written to a temporary directory)."""
    import riley

    mesh, camera, config = riley_setup(size, *PLATE_ELEMENTS, sub_sample=1, k1=k1)
    maps = {f.name: f.name in ("full_stats_save_xi_map", "full_stats_save_eta_map")
            for f in dataclasses.fields(config) if f.name.startswith("full_stats_save_")}
    config = dataclasses.replace(config, **maps, report=riley.ReportMode.full_stats,
                                 save_strategy=riley.SaveStrategy.disk)
    with tempfile.TemporaryDirectory() as d, _quiet():
        riley.raster(mesh, camera, config, out_dir=d)
        maps = [np.fromstring(Path(d, f"diag_cam0_frame0_{k}.csv").read_text().replace("\n", ","), sep=",")
                for k in ("xi", "eta")]
    W, H = size
    return tuple(m[:W * H].reshape(H, W) for m in maps)


def riley_call(size: tuple[int, int], k1: float):
    """A callable: one riley render at 4 spp into memory, returning its (H, W) image (0–255)."""
    import riley

    mesh, camera, config = riley_setup(size, *PLATE_ELEMENTS, sub_sample=math.isqrt(SPP), k1=k1)
    return lambda: np.squeeze(riley.raster(mesh, camera, config))


# ---- the oracle ------------------------------------------------------------------------------------
def material_points(mesh, element: np.ndarray, xi: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """Points (n, 3) mm on the plate of elements ``element`` at local (ξ, η)."""
    return bl.bilinear(mesh.nodes[mesh.quads[element]], xi, eta)


def reference(renderer: Renderer, camera: int, size: tuple[int, int]) -> dict:
    """The oracle on one variant: pixel-centre elements and material points, the interior
    mask (all sub-samples on the plate), and its 4 spp cubic images on glsim's reference image
    and on riley's texture (grey levels 0–255)."""
    view = renderer.view(camera, 0)
    W, H = size
    r = oracle.rasterize(view, "exact", 1)
    element, xi, eta = r["element"], r["xi"], r["eta"]
    hit = element >= 0
    points = np.full((H * W, 3), np.nan)
    points[hit] = material_points(renderer.mesh, element[hit], xi[hit], eta[hit])
    s = math.isqrt(SPP)
    r = oracle.rasterize(view, "exact", s)
    sub = np.flatnonzero(r["element"] >= 0)
    g = plate_geometry(size)
    P = material_points(renderer.mesh, r["element"][sub], r["xi"][sub], r["eta"][sub])
    texel = np.stack([P[:, 0] / g["width"] + 0.5, 0.5 - P[:, 1] / g["height"]], 1) * (PLATE_TEXTURE_PX - 1)
    images = {}
    for name, background, grey in (
            ("glsim", renderer.scene.render.background, lambda: renderer.backend.sampler("cubic")(r["ref_uv"][sub])),
            ("riley", 0.0, lambda: interp.sample(interp.prepare(np.pad(riley_texture(size), EDGE, mode="edge"),
                                                               "cubic", np.float64), texel + EDGE, "cubic") / 255.0)):
        a = np.full(H * s * W * s, float(background))
        a[sub] = grey()
        images[name] = a.reshape(H, s, W, s).mean(axis=(1, 3)) * 255.0
    covered = (r["element"] >= 0).reshape(H, s, W, s).all(axis=(1, 3))
    return {"element": element.reshape(H, W), "xi": xi.reshape(H, W), "eta": eta.reshape(H, W),
            "points": points.reshape(H, W, 3), "interior": covered, "images": images,
            "px_per_mm": g["fx"] / g["distance"]}


def riley_elements(ref: dict, xi: np.ndarray, eta: np.ndarray, tol: float = 1e-6) -> tuple[np.ndarray, int]:
    """riley's element per pixel (it writes no element map): the oracle's, except where riley's
    (ξ, η) lies on the element boundary opposite the oracle's (a pixel centre on a shared edge,
    whose element is ambiguous): there the neighbour across that edge (plate layout e = iy·nx + ix).
    Also how many pixels took a neighbour."""
    shift = []
    for mine, theirs in ((xi, ref["xi"]), (eta, ref["eta"])):
        edge = np.abs(mine) > 1 - tol
        shift.append(np.where(edge, np.rint((theirs - mine) / 2), 0).astype(np.int64))
    moved = (shift[0] != 0) | (shift[1] != 0)
    return ref["element"] + shift[0] + PLATE_ELEMENTS[0] * shift[1], int(np.count_nonzero(moved & (ref["element"] >= 0)))


def errors(points: np.ndarray, covered: np.ndarray, image: np.ndarray | None, ref: dict, name: str) -> dict:
    """Mapping error |X − X_oracle| (camera px) over pixels covered in both, coverage, and the
    grey error |image − oracle image| (8-bit levels) over the interior pixels."""
    exact = ref["element"] >= 0
    both = covered & exact
    d = np.linalg.norm(points[both] - ref["points"][both], axis=-1) * ref["px_per_mm"]
    out = {"map_rms_px": float(np.sqrt(np.mean(d * d))), "map_max_px": float(d.max()),
           "coverage": float(np.mean(covered)), "only_here": int(np.count_nonzero(covered & ~exact)),
           "only_oracle": int(np.count_nonzero(exact & ~covered))}
    if image is not None:
        g = np.abs(image.astype(np.float64)[ref["interior"]] * (255.0 if name == "glsim" else 1.0)
                   - ref["images"][name][ref["interior"]])
        out |= {"grey_rms": float(np.sqrt(np.mean(g * g))), "grey_max": float(g.max())}
    return out


# ---- the run --------------------------------------------------------------------------------------
def _riley_version() -> str | None:
    try:
        import riley  # noqa: F401
        from importlib.metadata import version
        return version("riley-raster")
    except ImportError:
        return None


def peer(size: tuple[int, int] = FULL_SIZE, reps: int = REPS, log=print) -> dict:
    """Every row: riley and the GL modes per distortion variant, timed interleaved, errors measured."""
    version = _riley_version()
    rows, calls, images, refs = [], {}, {}, {}
    plate = scene(size)
    t = time.perf_counter()
    with Renderer(plate, "cpu") as cpu:
        for cam, k1 in enumerate(K1S):
            refs[k1] = reference(cpu, cam, size)
    log(f"glsim bench peer: oracle ({time.perf_counter() - t:.0f} s)")
    with Renderer(plate, "gl") as gl:
        machine = machine_info(gl_info(gl))
        for cam, k1 in enumerate(K1S):
            if version:
                xi, eta = riley_coordinates(size, k1)
                covered = np.isfinite(xi) & np.isfinite(eta)
                own = covered & (refs[k1]["element"] >= 0)
                element, moved = riley_elements(refs[k1], np.where(own, xi, 0), np.where(own, -eta, 0))
                pts = np.full(xi.shape + (3,), np.nan)
                pts[own] = material_points(gl.mesh, element[own], xi[own], -eta[own])
                rows.append({"renderer": f"riley-raster {version}", "k1": k1, "status": "ok", "seconds_all": [],
                             "edge_pixels": moved, "errors": (pts, covered)})
                calls[len(rows) - 1] = riley_call(size, k1)
            for combo in COMBOS:
                truth = gl.render(cam, 0, truth=True, **dataclasses.replace(combo, spp=1).options()).truth
                pts = np.full(truth.mask.shape + (3,), np.nan)
                pts[truth.mask] = material_points(gl.mesh, truth.element[truth.mask], truth.xi[truth.mask],
                                                  truth.eta[truth.mask])
                rows.append({"renderer": label(gl, combo), "k1": k1, "status": "ok", "seconds_all": [],
                             "errors": (pts, truth.mask)})
                calls[len(rows) - 1] = (lambda cam=cam, combo=combo: gl.render(cam, 0, **combo.options()).image)
        for i, call in calls.items():                      # one warm-up each
            images[i] = call()
        for rep in range(reps):                            # interleaved: every row once per repetition
            for i, call in calls.items():
                t = time.perf_counter()
                images[i] = call()
                rows[i]["seconds_all"].append(time.perf_counter() - t)
            log(f"glsim bench peer: repetition {rep + 1}/{reps}")
    for i, row in enumerate(rows):
        name = "riley" if row["renderer"].startswith("riley") else "glsim"
        row |= errors(*row.pop("errors"), images[i], refs[row["k1"]], name)
        row["seconds"] = statistics.median(row["seconds_all"])
    for row in rows:
        riley = next((r for r in rows if r["k1"] == row["k1"] and r["renderer"].startswith("riley")), None)
        riley = riley if riley is not row else None
        row["glsim_over_riley"] = row["seconds"] / riley["seconds"] if riley else None
        row["riley_over_glsim"] = riley["seconds"] / row["seconds"] if riley else None
    if not version:
        rows = [{"renderer": "riley-raster", "k1": k1, "status": "not installed"} for k1 in K1S] + rows
    report = {"machine": machine, "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
              "size": list(size), "reps": reps, "spp": SPP, "elements": list(PLATE_ELEMENTS), "rows": rows}
    report["goals"] = goals(report)
    return report


# ---- report -----------------------------------------------------------------------------------------
def goals(report: dict) -> list[dict]:
    """The peer goals (glsim's time against riley-raster's at equal accuracy) on this run (met None where riley was not measured)."""
    ok = [r for r in report["rows"] if r["status"] == "ok" and r.get("glsim_over_riley") is not None]

    def worst(rows):  # the slowest variant of the best qualifying renderer per variant
        best = {}
        for r in rows:
            if r["k1"] not in best or r["glsim_over_riley"] < best[r["k1"]]["glsim_over_riley"]:
                best[r["k1"]] = r
        return list(best.values())

    exact = worst([r for r in ok if " exact " in r["renderer"] and r["map_max_px"] <= TARGET_MAP_MAX_PX])
    fast = worst([r for r in ok if " fast " in r["renderer"]])

    def measured(rows):
        return "; ".join(f"k1 = {r['k1']:g}: {r['renderer'][9:]} {r['glsim_over_riley']:.2f}× "
                         f"({r['seconds']:.3g} s)" for r in rows) or "not measured"

    def met(rows, target):
        return None if len(rows) < len(K1S) else max(r["glsim_over_riley"] for r in rows) <= target

    W, H = report["size"]
    at = "" if (W, H) == FULL_SIZE else f" (measured at {W}×{H}; the goal is for {FULL_SIZE[0]}×{FULL_SIZE[1]})"
    return [{"goal": f"exact (mapping max ≤ {TARGET_MAP_MAX_PX:g} px), 4 spp: glsim / riley time ≤ {GOAL_EXACT_RATIO:g}",
             "measured": measured(exact) + at, "met": met(exact, GOAL_EXACT_RATIO)},
            {"goal": f"the same, stretch: ≤ {GOAL_EXACT_STRETCH:g}", "measured": measured(exact) + at,
             "met": met(exact, GOAL_EXACT_STRETCH)},
            {"goal": f"fast, 4 spp: glsim / riley time ≤ {GOAL_FAST_RATIO:g}", "measured": measured(fast) + at,
             "met": met(fast, GOAL_FAST_RATIO)}]


_g = partial(num, missing="—")          # a table cell: a figure, or "—" where the run has none


HEADER = ("| renderer | k1 | time median (s) | min–max (s) | glsim / riley | riley / glsim | map RMS (px) "
          "| map max (px) | coverage | only here / only oracle | grey RMS | grey max |\n|" + "---|" * 12)

LEGEND = """\
Plate: {nx}×{ny} quad4, face-on, 600 mm from the camera, {W}×{H} px, Catmull–Rom cubic, {spp} spp
(2×2 sub-samples). riley: `riley.raster` into memory, default thread count, its own {tex}² uint8
texture. glsim: `Renderer.render` (auto-sized reference image; fast is always fp32; "newton":
`subsamples = "newton"`, sub-samples placed by Newton from the pixel centre, whose map columns
are the pixel centres' and whose grey columns show the sub-samples).

- **time**: wall seconds (perf_counter) per call; one warm-up each, then {reps} repetition(s), each
  rendering once with every row in turn (interleaved); median and fastest–slowest.
- **glsim / riley**, **riley / glsim**: median time ratios against riley at the same k1.
- **map RMS / max**: distance between the row's material point and the float64 CPU oracle's
  (exact mode) at 1 spp pixel centres covered by both, in camera px (mm × fx / 600 mm).
  riley's points come from its full_stats ξ/η maps with the element taken from the oracle at
  that pixel (riley writes no element map) and η negated (its world y is glsim's −y); where a
  pixel centre lies on an element edge and riley's ξ or η is ±1 on the other side, the
  neighbour across that edge ({edge} such pixels in this run).
- **coverage**: share of pixel centres on the plate; **only here / only oracle**: pixels covered
  by this row but not by the oracle, and the other way round.
- **grey RMS / max**: |image − oracle image| in 8-bit grey levels over the pixels whose 4 oracle
  sub-samples all hit the plate. Oracle image for riley: the oracle's sub-sample points sampled
  with Catmull–Rom on riley's texture (taps beyond its edge clamped, as riley does); for glsim:
  the oracle rendered with the same settings on glsim's reference image. Each renderer against
  the oracle on its own texture: the renderer's own error, not a riley–glsim image difference.
"""


def markdown(report: dict) -> str:
    """Machine line, table, legend, goals."""
    W, H = report["size"]
    lines = ["# glsim peer benchmark: riley-raster", "", f"{machine_line(report['machine'])}; {report['date']}", "",
             HEADER]
    for r in report["rows"]:
        if r["status"] != "ok":
            lines.append(f"| {r['renderer']} | {r['k1']:g} | {r['status']} |" + " |" * 9)
            continue
        lines.append(f"| {r['renderer']} | {r['k1']:g} | {_g(r['seconds'])} | {_g(min(r['seconds_all']))}–"
                     f"{_g(max(r['seconds_all']))} | {_g(r['glsim_over_riley'], '.2f')} | "
                     f"{_g(r['riley_over_glsim'], '.2f')} | {_g(r['map_rms_px'], '.2e')} | {_g(r['map_max_px'], '.2e')} "
                     f"| {r['coverage']:.1%} | {r['only_here']} / {r['only_oracle']} | {_g(r['grey_rms'])} "
                     f"| {_g(r['grey_max'])} |")
    lines += ["", LEGEND.format(nx=report["elements"][0], ny=report["elements"][1], W=W, H=H, spp=report["spp"],
                                tex=PLATE_TEXTURE_PX, reps=report["reps"],
                                edge=", ".join(f"k1 = {r['k1']:g}: {r['edge_pixels']}" for r in report["rows"]
                                               if "edge_pixels" in r) or "riley not run"),
              "## Goals (glsim against riley-raster)", "", "| goal | measured | met |", "|---|---|---|"]
    lines += [f"| {g['goal']} | {g['measured']} | {'—' if g['met'] is None else 'yes' if g['met'] else 'no'} |"
              for g in report["goals"]]
    return "\n".join(lines) + "\n"


def write(report: dict, out) -> str:
    """peer.json and peer.md into ``out``; returns the markdown."""
    return write_results(report, markdown(report), out, "peer")
