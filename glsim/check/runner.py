"""``glsim check``: does the GL path give the oracle's answer on this machine's driver?

A fixed set of small scenes is rendered on the GL backend and compared with the CPU oracle
(numpy float64) or a closed form. Each check prints its bound, the measured value and
pass/fail; the command names the driver, exits 1 on a failure and writes the report as JSON.
It runs them in child processes (:func:`run_isolated`), so that a driver that crashes in one
still gives the whole report. Each bound says where it comes from (``why``):

- float64 primitives bit for bit: the double path's building blocks against their numpy twins
  (a driver that contracts or folds where ``precise`` forbids it, or computes doubles in float,
  fails here first);
- coverage: a plate whose outline passes through pixel centres, with numbers that are not
  dyadic, at rigid shifts of 0 and ±1e-7 … ±1e-2 px: the closed form of the tie rule (README,
  "Conventions"), pixel for pixel;
- mapping and truth on the bulge pair, in units of their bounds (glsim.check.closed_forms, where
  each is derived): float64 in exact and q4, float32 vertex projection in fast;
- the same on curved quadratic elements (the Q8 paraboloid of ``glsim bench quadratic``):
  Newton on each patch in the shader, float64, exact and q4;
- the float32 exact build's reference points and ties (glsim.check.exact32), the float32
  q4 build's image (oracle_maps.renderer_q4_fp32);
- the GPU's shape filter: every step with a zero-area, tiny or folded element flagged
  (glsim.check.shapefilter);
- each optical effect on the bulge against the oracle, per pixel in units of its derived bound
  (oracle_maps.renderer_lit, renderer_dof, renderer_noise); the same for motion over the exposure
  seen by a rolling shutter (one-row renders in their own states: oracle_maps.renderer_motion);
- the camera passes (vignetting, Gaussian and Airy PSFs, fixed-pattern noise) on GL's own image
  against the oracle's stages on it, in units of their float32 bound.
"""
from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glsim.check import closed_forms, oracle_maps
from glsim.render import Renderer
from glsim.scene import Plate, Scene, Specimen, bulge_scene, demo_effects
from glsim.scene import bilinear as bl
from glsim.scene.camera import Camera, distort, normalized_to_pixel, pixel_to_normalized

FULL_SCALE = "of full scale"   # grey levels as Result.image holds them
SHIFTS = [0.0] + [s * m for m in (1e-7, 1e-6, 1e-5, 1e-4, 9e-4, 1 / 256, 1e-2) for s in (1, -1)]
BULGE_SIZE = (406, 308)
CURVED_SIZE = (160, 128)   # the Q8 paraboloid: 12 elements of about 36 px


@dataclass(frozen=True)
class Check:
    """One check: ``run(gl, cpu)`` → the measured value, passed when ≤ ``bound`` (``unit``)."""
    name: str
    bound: float
    unit: str
    why: str
    run: Callable[["Context"], float]


@dataclass
class Context:
    """The renderers a run shares (made on first use, closed at the end), the GL context, and
    what a check reports beside its value (``detail``, by check name: the report's row keeps it)."""
    ctx: object
    _pairs: dict = dataclasses.field(default_factory=dict)
    detail: dict = dataclasses.field(default_factory=dict)
    absolute: list = dataclasses.field(default_factory=list)   # the running check's (lowest, highest, unit)

    def bound(self, bound, where, unit: str) -> None:
        """Note the absolute bound a "× bound" check divided by (a number, or per pixel: its
        pixels ``where`` compared), so that its row reports the range beside the ratio."""
        b = np.broadcast_to(np.asarray(bound, np.float64), np.shape(where))[where]
        if b.size:
            self.absolute.append((float(b.min()), float(b.max()), unit))

    def pair(self, name: str, scene: Scene, mesh=None) -> tuple[Renderer, Renderer]:
        if name not in self._pairs:
            self._pairs[name] = (Renderer(scene, "gl", ctx=self.ctx, mesh=mesh), Renderer(scene, "cpu", mesh=mesh))
        return self._pairs[name]

    def close(self) -> None:
        for g, c in self._pairs.values():
            g.close()
            c.close()


# ---- float64 primitives ------------------------------------------------------------------------
def fp64_probe(ctx, n: int = 4096, seed: int = 25) -> dict[str, int]:
    """shaders/fp64_probe.comp on ``n`` random inputs against numpy: the number of results that
    differ in any bit, per primitive (split_double, pixel_to_normalized, pinhole_corners, edge
    functions and their gradients, distort, normalized_to_pixel). split_double's twin: x with its low 29 mantissa bits
    cleared, and float32(x − that)."""
    from glsim.backends.gl.programs import ProgramCache

    rng = np.random.default_rng(seed)
    x = rng.standard_normal(n) * 10.0 ** rng.uniform(-6, 3, n)
    uv = rng.uniform(-10, 2000, (n, 2)) + rng.integers(0, 3, (n, 1)) / 3
    intr = np.column_stack([rng.uniform(500, 5000, n), rng.uniform(500, 5000, n), rng.uniform(-2, 2, n),
                            rng.uniform(100, 1000, n), rng.uniform(100, 1000, n)]) / 3
    P = rng.uniform(-50, 50, (n, 4, 3)) + [0, 0, 300.0]
    q = rng.uniform(-10, 2000, (n, 2)) / 7
    k = rng.uniform(-0.3, 0.3, (n, 12)) * [1, 0.3, 0.01, 0.01, 0.1, 0.1, 0.03, 0.01, 0.01, 0.01, 0.01, 0.01]
    xn = rng.uniform(-0.6, 0.6, (n, 2))
    data = np.column_stack([x, uv, intr, P.reshape(n, 12), q, k, xn])
    cache = ProgramCache(ctx)
    bufs = [ctx.buffer(np.ascontiguousarray(data, "f8").tobytes()), ctx.buffer(reserve=n * 32 * 8)]
    try:
        prog = cache.compute("fp64_probe.comp", {"FP64": None})
        for i, b in enumerate(bufs):
            b.bind_to_storage_buffer(i)
        prog["u_count"].value = n
        prog.run(group_x=(n + 63) // 64)
        got = np.frombuffer(bufs[1].read(), "f8").reshape(n, 32)
    finally:
        for b in bufs:
            b.release()
        cache.release()
    hi = (x.view(np.uint64) & np.uint64(2**64 - 2**29)).view(np.float64)
    lo = (x - hi).astype(np.float32).astype(np.float64)
    A = np.stack([bl.pinhole_corners(P[i], intr[i]) for i in range(n)])
    E, m = bl.edge_functions_ray(A, q)
    want = {"split_double": (got[:, :2], np.column_stack([hi, lo])),
            "pixel_to_normalized": (got[:, 2:4], np.stack([pixel_to_normalized(uv[i], intr[i]) for i in range(n)])),
            "pinhole_corners": (got[:, 4:16], A.reshape(n, 12)),
            "edge_functions": (got[:, 16:28], np.column_stack([E, m.reshape(n, 8)])),
            "distort": (got[:, 28:30], np.stack([distort(xn[i], k[i]) for i in range(n)])),
            "normalized_to_pixel": (got[:, 30:32], np.stack([normalized_to_pixel(distort(xn[i], k[i]), intr[i])
                                                             for i in range(n)]))}
    return {k: int(np.any(a.view(np.uint64) != b.view(np.uint64), axis=-1).sum()) for k, (a, b) in want.items()}


def _probe(c: Context) -> float:
    if "GL_ARB_gpu_shader_fp64" not in c.ctx.extensions:
        return float("nan")   # reported as "no float64" (check_row)
    counts = fp64_probe(c.ctx)
    c.detail["float64 primitives"] = counts   # which primitive differs, where any does
    return float(sum(counts.values()))


# ---- coverage -----------------------------------------------------------------------------------
OUTLINE_CAM = Camera(name="c", size=(480, 360), fx=1500.0, fy=1500.0, cx=240.0, cy=180.0)


def outline_plate(shifts_px=SHIFTS[1:]) -> Scene:
    """A 48 × 36 mm plate of 8 × 6 elements of 30 px at 300 mm (5 px/mm: the outline's rays
    ±0.08, ±0.06 are not dyadic), outline on pixel centres (120, 360; 90, 270) at step 0; step
    k is the rigid shift (δ, −δ/2) px, δ = shifts_px[k − 1]."""
    plate = Plate(width=48, height=36, nx=8, ny=6, translations=tuple((d / 5, -d / 10, 0.0) for d in shifts_px))
    return Scene(cameras=(OUTLINE_CAM,), specimen=Specimen(plate=plate, t=(0.0, 0.0, 300.0)))


def outline_owner(d: float) -> np.ndarray:
    """The element owning each pixel centre of the plate shifted by (d, −d/2) px under the tie
    rule (half-open boxes u0 ≤ u < u1, v0 ≤ v < v1), −1 outside."""
    i = np.floor((np.arange(480) - (120 + d)) / 30).astype(int)
    j = np.floor((np.arange(360) - (90 - d / 2)) / 30).astype(int)
    ok = (i[None, :] >= 0) & (i[None, :] < 8) & (j[:, None] >= 0) & (j[:, None] < 6)
    return np.where(ok, j[:, None] * 8 + i[None, :], -1)


def _coverage(mode: str) -> Callable[[Context], float]:
    def run(c: Context) -> float:
        g, _ = c.pair("outline", outline_plate())
        return float(sum(int((g.render(0, k, truth=True, mode=mode).truth.element != outline_owner(d)).sum())
                         for k, d in enumerate(SHIFTS)))
    return run


# ---- the bulge pair -----------------------------------------------------------------------------
def _bulge(c: Context):
    return c.pair("bulge", bulge_scene(size=BULGE_SIZE, steps=1))


def _curved(c: Context):
    from glsim.bench import quadratic

    return c.pair("quad8", quadratic.paraboloid_scene(CURVED_SIZE), quadratic.mesh("quad8", 4, 3))


def _mapping(mode: str, spp: int, what: str, pair=_bulge) -> Callable[[Context], float]:
    """Over the cameras of ``pair``'s scene (the bulge's two by default) at step 1, GL against
    the oracle in the same mode: the largest |Δref_uv| (px) or |ΔX_deformed| (mm) in units of
    its bound (glsim.check.closed_forms: float64, or fast's per pixel), or the largest |Δgrey|
    off the coverage ties in units of its bound (:func:`_grey_ratio`)."""
    def run(c: Context) -> float:
        g, o = pair(c)
        worst = 0.0
        for cam in range(len(g.scene.cameras)):
            a = g.render(cam, 1, truth=True, mode=mode, samples_per_pixel=spp)
            b = o.render(cam, 1, truth=True, mode=mode, samples_per_pixel=spp)
            both = a.truth.mask & b.truth.mask
            if what == "grey":
                v = _grey_ratio(c, g, o, a, b, mode, cam, spp)
            else:
                field = b.truth.ref_uv if what == "ref" else b.truth.X_deformed
                other = a.truth.ref_uv if what == "ref" else a.truth.X_deformed
                bound = closed_forms.mapping(mode, a.camera.fx, field, b.truth.mask)
                c.bound(bound, both, "px" if what == "ref" else "mm")
                v = (np.linalg.norm(other - field, axis=-1) / bound)[both].max()
            worst = max(worst, float(v))
        return worst
    return run


def _fp32_exact(what: str) -> Callable[[Context], float]:
    """Over the bulge's cameras at step 1, GL's float32 exact build (precision fp32: CAMERA_LOCAL,
    REF_LOCAL) against the oracle's exact: the largest |Δref_uv| off its ties in units of its
    bound (glsim.check.exact32.renderer_mapping), or the pixels whose mask or element
    differs off its ties (exact32.renderer_ties); NaN (skipped) on a driver
    without float64, which the build's records need."""
    def run(c: Context) -> float:
        from glsim.check import exact32

        g, o = _bulge(c)
        if not g.backend.fp64:
            return float("nan")
        worst = 0.0
        for cam in range(len(g.scene.cameras)):
            a = g.render(cam, 1, truth=True, mode="exact", precision="fp32").truth
            b = o.render(cam, 1, truth=True, mode="exact").truth
            off = ~exact32.renderer_ties(g, cam, 1)
            if what == "ref":
                bound = exact32.renderer_mapping(g, b, cam, 1) + closed_forms.FLOAT64
                c.bound(bound, a.mask & b.mask & off, "px")
                v = (np.linalg.norm(a.ref_uv - b.ref_uv, axis=-1) / bound)[a.mask & b.mask & off].max()
            else:
                v = (((a.mask ^ b.mask) | (a.mask & b.mask & (a.element != b.element))) & off).sum()
            worst = max(worst, float(v))
        return worst
    return run


def _q4_fp32(c: Context) -> float:
    """Over the bulge's cameras at step 1, GL's float32 q4 build (precision fp32) against the
    oracle's q4: the largest |Δgrey| off its ties in units of oracle_maps.renderer_grey at its
    reference points' bound (closed_forms.interpolated at closed_forms.q4_fp32_px; the ties within that
    distance of an edge: oracle_maps.renderer_q4_fp32)."""
    g, o = _bulge(c)
    worst = 0.0
    for cam in range(len(g.scene.cameras)):
        a = g.render(cam, 1, mode="q4", precision="fp32")
        b = o.render(cam, 1, truth=True, mode="q4")
        px, ties = oracle_maps.renderer_q4_fp32(g, cam, 1)
        worst = max(worst, _grey_ratio(c, g, o, a, b, "q4", cam, 1, closed_forms.interpolated(px, b.truth.ref_uv, b.truth.mask),
                                       ties))
    return worst


def _shape_filter(c: Context) -> float:
    """Steps in which numpy finds a zero-area, tiny or folded element that the GPU's shape
    filter (shaders/shape.comp) does not flag, in either build, over 20 random meshes of each
    kind where float32's rounding decides (glsim.check.shapefilter)."""
    from glsim.check.shapefilter import misses

    return float(misses(c.ctx)[0])


def _grey_ratio(c: Context, g, o, a, b, mode: str, cam: int, spp: int, shift=None, ties=None) -> float:
    """The largest |Δgrey| of GL's image ``a`` (renderer ``g``, camera ``cam``, step 1) against
    the oracle's ``b`` (renderer ``o``; ``b``'s truth at 1 spp) where no sample lies at a
    coverage tie (``ties``, by default oracle_maps.renderer_ties), in units of oracle_maps.renderer_grey:
    GL's reference points within ``shift`` of the oracle's (by default closed_forms.mapping: float64's
    bound in exact and q4, fast's per pixel)."""
    if shift is None:
        shift = closed_forms.mapping(mode, a.camera.fx, b.truth.ref_uv, b.truth.mask)
    if ties is None:
        ties = oracle_maps.renderer_ties(g, mode, cam, 1, spp)
    bound = oracle_maps.renderer_grey(o, mode, cam, 1, spp, shift, b.truth)
    c.bound(bound, ~ties, FULL_SCALE)
    return float(closed_forms.units(np.abs(a.image.astype(np.float64) - b.image), bound)[~ties].max())


def _one_effect(effect: str) -> Scene:
    """The demo's effects on the bulge with ``effect`` alone kept."""
    scene = demo_effects(bulge_scene(size=BULGE_SIZE, steps=1))
    return dataclasses.replace(scene, **{e: (getattr(scene, e) if e == effect else None)
                                         for e in ("lighting", "optics", "noise")})


def _effect(effect: str) -> Callable[[Context], float]:
    """One of the demo's effects alone on the bulge, exact, camera 1: the largest |Δgrey| off the
    coverage ties in units of its bound — oracle_maps.renderer_lit from the unlit grey's bound, or
    oracle_maps.renderer_noise / renderer_dof from the oracle's image without the effect and its bound
    (the blur's σ ties left out too)."""
    def run(c: Context) -> float:
        g, o = c.pair(effect, _one_effect(effect))
        a = g.render(1, 1, mode="exact")
        ties = oracle_maps.renderer_ties(g, "exact", 1, 1)
        b = o.render(1, 1, mode="exact")
        if effect == "lighting":
            bound = oracle_maps.renderer_lit(o, "exact", 1, 1)
        elif effect == "noise":
            bound = oracle_maps.renderer_noise(o, 1, 1, *oracle_maps.without(o, effect, "exact", 1, 1))
        else:
            bound, blur_ties = oracle_maps.renderer_dof(o, "exact", 1, 1, *oracle_maps.without(o, effect, "exact", 1, 1))
            ties |= blur_ties
        c.bound(bound, ~ties, FULL_SCALE)
        return float(closed_forms.units(np.abs(a.image.astype(np.float64) - b.image), bound)[~ties].max())
    return run


def _motion(c: Context) -> float:
    """Camera 1 of the bulge rotating and moving over a 2-sample exposure seen by a rolling
    shutter (its rows rendered by one-row cameras, each in its own state), exact: the largest
    |Δgrey| off the coverage ties in units of oracle_maps.renderer_motion (the sub-frames' bounds,
    averaged, and the mean's rounding)."""
    scene = bulge_scene(size=BULGE_SIZE, steps=1).replace(
        exposure={"time": 0.002, "samples": 2, "velocity": [300.0, 0.0, 0.0], "angular_velocity": [0.0, 0.0, 1.0]},
        sensor={"line_time": 2e-5})
    g, o = c.pair("motion", scene)
    bound, ties = oracle_maps.renderer_motion(g, o, "exact", 1, 1)
    a, b = g.render(1, 1, mode="exact"), o.render(1, 1, mode="exact")
    c.bound(bound, ~ties, FULL_SCALE)
    return float(closed_forms.units(np.abs(a.image.astype(np.float64) - b.image), bound)[~ties].max())


def _camera_passes(effects: dict) -> Callable[[Context], float]:
    """GL's bulge image (camera 0, step 1, exact) with camera passes (``effects``: scene tables)
    against the oracle's camera stages (glsim.backends.cpu.camera_stages, float64) applied to
    GL's own image without them — the same input, so only the passes' arithmetic differs — in
    units of :func:`glsim.check.closed_forms.camera_passes`."""
    def run(c: Context) -> float:
        from glsim.backends.cpu import camera_stages
        from glsim.effects import prepare

        g0, _ = _bulge(c)
        scene = g0.scene.replace(**effects)
        g, _ = c.pair(f"camera passes {sorted(effects)} {effects.get('psf', {}).get('kind')}", scene)
        plain, image = g0.render(0, 1).image, g.render(0, 1).image
        fx = prepare(scene, np.zeros((1, 3)), np.zeros((0, 4), np.int64), scene.cameras[0], 0, 1, np.empty(0),
                     normals=False)
        want = camera_stages(plain.astype(np.float64), fx, [])
        bound = closed_forms.camera_passes(fx, plain)
        c.bound(bound, True, FULL_SCALE)
        return float(np.abs(image.astype(np.float64) - want).max() / bound)
    return run


def _stages(c: Context) -> float:
    """Values of the bulge pair's images and truth (element, ξ, η, reference point; every mode
    at 1 and 4 spp, both cameras at step 1) that differ in any bit between the two pixel stages
    (glsim.backends.gl.plan: fragment passes on depth layers, compute passes over pixel lists;
    fast's triangles shaded in the fragment pass or from their records by a compute pass)."""
    from glsim.backends.gl.plan import PIXEL_STAGES

    g, _ = _bulge(c)
    differ = 0
    for mode, spp in (("exact", 1), ("exact", 4), ("q4", 1), ("q4", 4), ("fast", 1), ("fast", 4)):
        out = []
        for stage in PIXEL_STAGES:
            with g.backend.in_stage(stage):
                out.append([g.render(cam, 1, truth=True, mode=mode, samples_per_pixel=spp) for cam in (0, 1)])
        for a, b in zip(*out):
            for x, y in ((a.image, b.image), (a.truth.element, b.truth.element), (a.truth.xi, b.truth.xi),
                         (a.truth.eta, b.truth.eta), (a.truth.ref_uv, b.truth.ref_uv)):
                same = (x == y) | (np.isnan(x) & np.isnan(y)) if x.dtype.kind == "f" else x == y
                differ += int((~same).sum())
    return float(differ)


FLOAT64 = "glsim.check.closed_forms.FLOAT64: float64, 1e-9 px or mm"
GREY = ("glsim.check.oracle_maps.renderer_grey off coverage ties (oracle_maps.renderer_ties): the float32 reference "
        "sample and box filter, the samples' shift through the interpolant's gradient")
CAMERA = "glsim.check.closed_forms.camera_passes: float32 passes on GL's own image"
CHECKS = (
    Check("float64 primitives", 0, "results differing in any bit", "split_double, pixel_to_normalized, "
          "pinhole_corners, edge functions, distort, normalized_to_pixel: the same operations as numpy's, "
          "`precise` (4096 inputs)", _probe),
    Check("coverage exact, outline on pixel centres, 15 shifts", 0, "px off the tie rule",
          "ties decided at the exact pixel point (glsim.scene.bilinear.pinhole_corners)", _coverage("exact")),
    Check("coverage q4, outline on pixel centres, 15 shifts", 0, "px off the tie rule",
          "2-D edge functions at the exact pixel centres, the same float64 corners as the oracle", _coverage("q4")),
    Check("bulge exact 1 spp: reference point", 1, "× bound", FLOAT64, _mapping("exact", 1, "ref")),
    Check("bulge exact 1 spp: truth X", 1, "× bound", FLOAT64, _mapping("exact", 1, "X")),
    Check("bulge exact 4 spp: grey per pixel", 1, "× bound", GREY + ", the samples within 1e-9 px of the oracle's",
          _mapping("exact", 4, "grey")),
    Check("bulge fast 4 spp: grey per pixel", 1, "× bound", GREY + ", the samples within fast's float32 bound",
          _mapping("fast", 4, "grey")),
    Check("bulge exact fp32 1 spp: reference point", 1, "× bound", "glsim.check.exact32.renderer_mapping: "
          "the float32 solve relative to each element's centre and the reference projection (CAMERA_LOCAL, "
          "REF_LOCAL), off its ties", _fp32_exact("ref")),
    Check("bulge exact fp32 1 spp: coverage and elements", 0, "px off ties", "each edge's float32 edge function "
          "(glsim.check.exact32.edge_px, exact32.renderer_ties)", _fp32_exact("coverage")),
    Check("bulge q4 1 spp: reference point", 1, "× bound", FLOAT64, _mapping("q4", 1, "ref")),
    Check("bulge q4 fp32 1 spp: grey per pixel", 1, "× bound", "glsim.check.oracle_maps.renderer_q4_fp32 "
          "and interpolated: float32 corners as fast's vertices, invert_newton's relative coordinates and "
          "stopping step, the corners' float32 values interpolated; off its ties", _q4_fp32),
    Check("bulge fast 1 spp: reference point", 1, "× bound", "glsim.check.closed_forms.fast_bound: float32 vertex "
          "projection, fx·12·2^-24 px times the reference pixels per image pixel", _mapping("fast", 1, "ref")),
    Check("quadratic Q8 exact 1 spp: reference point", 1, "× bound", FLOAT64, _mapping("exact", 1, "ref", _curved)),
    Check("quadratic Q8 exact 1 spp: truth X", 1, "× bound", FLOAT64, _mapping("exact", 1, "X", _curved)),
    Check("quadratic Q8 q4 1 spp: reference point", 1, "× bound", FLOAT64, _mapping("q4", 1, "ref", _curved)),
    Check("shape filter: excluded elements flagged", 0, "steps missed", "shaders/shape.comp's bounds on each "
          "element's area and fold against numpy's (float64 and float32 builds), so that a step it leaves "
          "unflagged has none: glsim.backends.gl.geometry.shape_candidates", _shape_filter),
    Check("pixel stages: compute against fragment", 0, "values differing in any bit", "each pass's "
          ".frag and .comp entry files on the same .glsl code (glsim.backends.gl.plan); images and "
          "truth of the bulge pair, every mode, 1 and 4 spp", _stages),
    Check("lighting, exact: grey per pixel", 1, "× bound", "glsim.check.oracle_maps.renderer_lit off coverage ties: the unlit "
          "grey's bound through the combine, shade.glsl's float32 arithmetic and light_at's point and normal",
          _effect("lighting")),
    Check("depth of field, exact: grey per pixel", 1, "× bound", "glsim.check.oracle_maps.renderer_dof off coverage "
          "and σ ties: the window's source bound, the expansion scheme's tolerance and rounding, σ's float32 error "
          "through the gather", _effect("optics")),
    Check("noise, exact: grey per pixel", 1, "× bound", "glsim.check.oracle_maps.renderer_noise off coverage ties: "
          "the noise-free image's bound through I + σ(I)·z and the noise pass's float32 error", _effect("noise")),
    Check("motion: exposure and rolling shutter, exact: grey per pixel", 1, "× bound", "glsim.check.oracle_maps."
          "renderer_motion off coverage ties: the same sub-frames as the oracle (docs/motion.md), each within its "
          "still render's bound, averaged, and the mean's float32 rounding", _motion),
    Check("camera passes: Gaussian PSF, vignetting, fixed pattern", 1, "× bound", CAMERA,
          _camera_passes({"psf": {"kind": "gaussian", "sigma": 0.8}, "vignetting": {"natural": True, "radial": [0.3]},
                          "sensor": {"prnu": 1.0, "dsnu": 2.0}})),
    Check("camera passes: Airy PSF (2-D kernel)", 1, "× bound", CAMERA,
          _camera_passes({"psf": {"kind": "airy", "wavelength_nm": 550.0, "f_number": 8.0, "pixel_pitch": 0.00345}})),
)


def run_checks(ctx=None, checks=CHECKS, progress=print, on_machine=None, on_row=None) -> dict:
    """Run ``checks`` on the GL context ``ctx`` (a new one if None); the report as a dict.
    ``on_machine(machine)`` is called once the driver is known, ``on_row(row)`` after each check."""
    from glsim.backends.gl.context import create_context, info
    from glsim.bench.report import machine_info

    own = ctx is None
    ctx = create_context() if own else ctx
    c = Context(ctx)
    rows = []
    t_all = time.perf_counter()
    try:
        machine = machine_info(info(ctx))
        if on_machine is not None:
            on_machine(machine)
        for ch in checks:
            t0 = time.perf_counter()
            c.absolute.clear()
            value = ch.run(c)
            row = {"name": ch.name, "bound": ch.bound, "unit": ch.unit, "why": ch.why,
                   "value": None if np.isnan(value) else value,
                   "passed": None if np.isnan(value) else bool(value <= ch.bound),
                   "seconds": round(time.perf_counter() - t0, 2)}
            if c.absolute:   # over the cameras and images the check compared
                row["absolute_bound"] = {"min": min(a[0] for a in c.absolute), "max": max(a[1] for a in c.absolute),
                                         "unit": c.absolute[0][2]}
            if ch.name in c.detail:
                row["detail"] = c.detail.pop(ch.name)
            rows.append(row)
            progress(check_row(row))
            if on_row is not None:
                on_row(row)
    finally:
        c.close()
        if own:
            ctx.release()
    return _report(machine, rows, t_all)


def _report(machine: dict | None, rows: list[dict], t_all: float) -> dict:
    return {"machine": machine, "date": time.strftime("%Y-%m-%d"), "seconds": round(time.perf_counter() - t_all, 1),
            "passed": all(r["passed"] is not False for r in rows), "checks": rows}


def run_isolated(checks=CHECKS, progress=print) -> dict:
    """:func:`run_checks` in child processes (forked before this process makes any GL context):
    a driver that crashes the process in a check (a segfault building or running its program)
    ends only the child. The checks it finished are kept, the one it was in is reported failed
    with how the child ended, and a new child goes on after it; so the report is whole however
    the driver behaves. Each child ends with this process (lifeline)."""
    import signal
    import sys
    import traceback

    from glsim.workflows.library.lifeline import die_with_parent

    rows, machine, todo, t_all = [], None, list(checks), time.perf_counter()
    while todo:
        parent = os.getpid()
        read, write = os.pipe()
        pid = os.fork()
        if pid == 0:   # the child: report each row (and the driver) as a JSON line
            status = 0
            try:
                os.close(read)
                die_with_parent(parent)
                with os.fdopen(write, "w") as out:
                    def send(key, value, out=out):
                        out.write(json.dumps({key: value}) + "\n")
                        out.flush()
                    run_checks(checks=todo, progress=progress, on_machine=lambda m: send("machine", m),
                               on_row=lambda r: send("row", r))
            except BaseException:   # noqa: BLE001 — printed; the parent reports the check as failed
                traceback.print_exc()
                status = 1
            finally:   # (os._exit skips the interpreter's flush of the rows printed)
                sys.stdout.flush()
                sys.stderr.flush()
                os._exit(status)
        os.close(write)
        t0, done = time.perf_counter(), 0
        with os.fdopen(read) as inp:
            for line in inp:
                msg = json.loads(line)
                if "machine" in msg:
                    machine = msg["machine"]
                else:
                    rows.append(msg["row"])
                    done += 1
                    t0 = time.perf_counter()
        status = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
        todo = todo[done:]
        if todo:   # the child ended inside todo[0]
            ch = todo.pop(0)
            how = (f"the process was killed by {signal.Signals(-status).name}" if status < 0
                   else f"an error ended the process (exit status {status}; its traceback above)")
            row = {"name": ch.name, "bound": ch.bound, "unit": ch.unit, "why": ch.why, "value": None,
                   "passed": False, "seconds": round(time.perf_counter() - t0, 2), "detail": {"crashed": how}}
            rows.append(row)
            progress(check_row(row))
    return _report(machine, rows, t_all)


def check_row(r: dict) -> str:
    state = "skipped (no float64)" if r["passed"] is None else "pass" if r["passed"] else "FAIL"
    value = "–" if r["value"] is None else f"{r['value']:.3g}"
    detail = "" if r["passed"] is not False or not r.get("detail") else \
        " — " + ", ".join(f"{k}: {v}" if k == "crashed" else f"{k} {v}" for k, v in r["detail"].items() if v)
    return f"{state:>6}  {r['name']}: {value} ≤ {r['bound']:.3g} {r['unit']}{_absolute(r)}  ({r['seconds']} s){detail}"


def _absolute(r: dict) -> str:
    """The absolute bound beside a "× bound" row: one value, or the range of a per-pixel bound."""
    a = r.get("absolute_bound")
    if not a:
        return ""
    span = f"{a['min']:.2g}" if a["min"] == a["max"] else f"{a['min']:.2g} … {a['max']:.2g}"
    return f" (bound {span} {a['unit']})"


def main(argv: list[str]) -> int:
    """glsim check [--json PATH]: exit 0 when every check passes, 1 otherwise."""
    import argparse

    from glsim.bench.report import machine_line
    from glsim.io import images as io

    ap = argparse.ArgumentParser(prog="glsim check", description="glsim check: does the GL path give the oracle's "
                                 "answer on this machine's driver? Prints each check's bound, value and pass/fail; "
                                 "exits 1 on a failure.")
    ap.add_argument("--json", help="also write the report here (bench/results/check-<driver>.json for the README)")
    ap.add_argument("--in-process", action="store_true",
                    help="run the checks in this process (by default each runs in a child process, so that a "
                         "driver that crashes in one still gives the whole report; here a crash ends the run)")
    ap.add_argument("--skip", action="append", default=[], metavar="TEXT",
                    help="leave out the checks whose name contains TEXT (repeatable): for a driver that cannot "
                         "build or crashes on their programs; the report lists them as not run")
    args = ap.parse_args(argv)
    skipped = [c.name for c in CHECKS if any(t in c.name for t in args.skip)]
    unknown = [t for t in args.skip if not any(t in c.name for c in CHECKS)]
    if unknown:
        ap.error(f"--skip {unknown[0]!r} matches no check's name; the checks are: "
                 + "; ".join(c.name for c in CHECKS))
    chosen = tuple(c for c in CHECKS if c.name not in skipped)
    left_out = f"not run ({' '.join(f'--skip {t}' for t in args.skip)}): {'; '.join(skipped)}"
    if skipped:
        print(left_out)
    report = run_checks(checks=chosen) if args.in_process or not hasattr(os, "fork") else run_isolated(chosen)
    report["skipped"] = skipped
    no_fp64 = [r["name"] for r in report["checks"] if r["passed"] is None]
    print(f"glsim check on {machine_line(report['machine'])}: "
          f"{'all passed' if report['passed'] else 'FAILED'} in {report['seconds']} s"
          + (f"; {left_out}" if skipped else "")
          + (f"; skipped (no float64): {'; '.join(no_fp64)}" if no_fp64 else ""))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        io.write_text(Path(args.json), json.dumps(report, indent=2) + "\n")
    return 0 if report["passed"] else 1
