"""Design specs: candidate set-ups (a base scene and ``[vary]``, expanded as a library's), the DIC
settings to compare, the realisations and the ranking, all checked before anything runs.

A spec is a TOML file::

    scene = "plate.toml"       # the base scene (relative to the spec) or an inline [scene] table
    seed = 1                   # seeds [vary]'s random draws (as a library spec)
    mode = "grid"              # [vary]'s expansion: grid, zip or random (with n)
    camera = "cam0"            # the camera whose images are measured (2-D DIC); default the first
    cameras = ["cam0", "cam1"] # engine pyvale3d: the stereo pair (camera 0's frame); default the first two
    step = 1                   # the deformed load step, measured against step 0; default the last
    engine = "quick"           # quick: the Cramér–Rao noise map only; pyvale2d: also pyvale's 2-D DIC;
                               # pyvale3d: pyvale's stereo DIC (X, Y, Z, U, V, W in mm)
    roi_margin = 4             # px: the ROI is the specimen's pixels at step 0 and at `step`, eroded

    [vary]                     # candidate set-ups: dotted scene paths → values (docs/library.md)
    noise.sigma = [1.0, 2.0]

    [dic]                      # DIC settings: every combination of these lists
    subset_size = [21, 31]     # px, odd
    subset_step = 10           # px between subset centres (a number or a list)
    shape_function = "affine"  # rigid (zero order), affine (first), quad (second); or a list
    strain_window = [5, 9]     # optional, with an engine: pyvale's strain window (subset centres a side, odd)
    strain_element = 9         # its fit: 4 (bilinear, Q4) or 9 (biquadratic, Q9); default 9 (pyvale's)
    strain_formulation = "HENCKY"   # GREEN, ALMANSI, HENCKY, BIOT_EULER, BIOT_LAGRANGE; default HENCKY

    [realisations]
    noise_seeds = [1, 2, 3]    # one noisy image set per seed (the scene's top-level seed)
    speckle_seeds = [0]        # speckle patterns (speckle.seed): pattern-induced bias

    [calibration]              # stereo only (calibration.py)
    rig = "exact"              # the scene's own cameras; "targets": calibrated from a simulated target library

    [resolution]               # optional, with an engine: the sinusoid sweep (resolution.py)
    periods_px = [16, 32, 64]  # periods of u(x) = A·sin(2πx/p) (stereo: W along the plate's normal), px at
                               # the plate; default from the subsets
    amplitude_px = 0.5         # A, px (the DIC Challenge 2.0 star's)

    [rank]
    by = "p95_abs_error_px"    # see CRITERIA

Nothing is rendered or written by :func:`load_design`.
"""
from __future__ import annotations

import difflib
import hashlib
import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path

from glsim.limits import MAX_VALUES
from glsim.workflows.design.calibration import CalibrationSpec, calibration_spec
from glsim.workflows.library.spec import LibraryPlan, SpecError, expand, read_spec

TOP_KEYS = ("scene", "seed", "mode", "n", "camera", "cameras", "step", "engine", "roi_margin", "vary", "dic",
            "realisations", "calibration", "resolution", "rank")
ENGINES = ("quick", "pyvale2d", "pyvale3d")
STEREO = "pyvale3d"
SHAPES = ("rigid", "affine", "quad")
DIC_KEYS = ("subset_size", "subset_step", "shape_function", "strain_window", "strain_element", "strain_formulation")
STRAIN_KEYS = DIC_KEYS[3:]
# pyvale.strain.calculate_2d's strain measures (from F = I + ∇u) and window elements
STRAIN_FORMULATIONS = ("GREEN", "ALMANSI", "HENCKY", "BIOT_EULER", "BIOT_LAGRANGE")
STRAIN_ELEMENTS = (4, 9)
MAX_STRAIN_WINDOW = 101
REAL_KEYS = ("noise_seeds", "speckle_seeds")
RES_KEYS = ("periods_px", "amplitude_px")
MIN_PERIOD_PX, MAX_PERIOD_PX, MAX_AMPLITUDE_PX = 4.0, 10_000.0, 5.0
# criterion → (what it is, needs the engine, smaller is better)
CRITERIA = {
    "p95_abs_error_px": ("95th percentile over subsets and realisations of |(U, V) − truth| (px)", True, True),
    "p95_abs_error_mm": ("the same in mm (through the camera scale at each subset)", True, True),
    "rms_bias_px": ("RMS over subsets of the bias map |mean over realisations − truth| (px)", True, True),
    "median_noise_px": ("median over subsets of the noise map (std over realisations of U and V, px)", True, True),
    "noise_floor_px": ("std of the static pair's measured U, V over subsets and realisations (px)", True, True),
    "spatial_resolution_px": ("period (px) at which the sinusoid's measured amplitude falls to 90 % ([resolution])",
                              True, True),
    "mei_px2": ("metrological efficiency indicator: noise floor × spatial resolution (px², [resolution])", True, True),
    "strain_spatial_resolution_px": ("period (px) at which the sinusoid's measured exx amplitude falls to 90 % of "
                                     "the analytic one ([resolution] and [dic] strain_window)", True, True),
    "strain_mei_px": ("strain's efficiency indicator: exx noise floor × strain spatial resolution (strain·px, "
                      "[resolution] and [dic] strain_window)", True, True),
    "valid_share": ("share of subsets converged above the ZNCC threshold (larger is better)", True, False),
    "p95_abs_strain_error": ("95th percentile over strain points, realisations and the components exx, eyy, exy "
                             "of |strain − truth| (strain, [dic] strain_window)", True, True),
    "rms_strain_bias": ("RMS over strain points and exx, eyy, exy of the strain bias map (mean over realisations "
                        "− truth; strain)", True, True),
    "median_strain_noise": ("median over strain points of the strain noise map (std over realisations, RMS of "
                            "exx, eyy, exy; strain)", True, True),
    "strain_noise_floor": ("std of the static pair's strain over strain points and realisations (RMS of exx, "
                           "eyy, exy; strain)", True, True),
    "quick_sigma_px": ("median over subsets of the Cramér–Rao σ_u, σ_v (px), quick mode", False, True),
    "quick_sigma_mm": ("the same in mm", False, True),
}
# stereo criteria (engine pyvale3d): mm, camera 0's frame; the quick ones stay 2-D, on camera 0
STEREO_CRITERIA = {
    "p95_abs_error_mm": ("95th percentile over subsets and realisations of |(U, V, W) − truth| (mm)", True, True),
    "p95_abs_W_mm": ("95th percentile over subsets and realisations of |W − truth| (mm, out of camera 0's plane)",
                     True, True),
    "p95_abs_Z_mm": ("95th percentile over subsets and realisations of the reference shape's |Z − truth| (mm)",
                     True, True),
    "rms_bias_mm": ("RMS over subsets of the bias map |mean over realisations of (U, V, W) − truth| (mm)", True, True),
    "rms_bias_W_mm": ("RMS over subsets of the bias map of W (mm)", True, True),
    "median_noise_mm": ("median over subsets of the noise map (std over realisations of U, V, W; RMS of the "
                        "three, mm)", True, True),
    "median_noise_W_mm": ("median over subsets of the noise map of W (mm)", True, True),
    "noise_floor_mm": ("std of the static pair's measured U, V, W over subsets and realisations (RMS of the "
                       "three, mm)", True, True),
    "noise_floor_W_mm": ("std of the static pair's measured W over subsets and realisations (mm)", True, True),
    **{k: (CRITERIA[k][0].replace("strain − truth", "surface strain − truth"), True, True)
       for k in ("p95_abs_strain_error", "rms_strain_bias", "median_strain_noise", "strain_noise_floor")},
    "valid_share": CRITERIA["valid_share"],
    "spatial_resolution_px": ("period (camera 0's px at the plate) at which an out-of-plane sinusoid W's measured "
                              "amplitude falls to 90 % ([resolution], stereo)", True, True),
    "spatial_resolution_mm": ("the same in mm on the plate", True, True),
    "mei_W_mm2": ("metrological efficiency indicator: W noise floor × spatial resolution (mm², [resolution])",
                  True, True),
    "strain_spatial_resolution_px": ("period (camera 0's px at the plate) at which an in-plane sinusoid's measured "
                                     "surface exx amplitude falls to 90 % of the analytic one ([resolution] and "
                                     "[dic] strain_window)", True, True),
    "strain_mei_px": CRITERIA["strain_mei_px"],
    "quick_sigma_px": CRITERIA["quick_sigma_px"],
    "quick_sigma_mm": CRITERIA["quick_sigma_mm"],
}
MAX_SUBSET = 301
RESOLUTION_CRITERIA = ("spatial_resolution_px", "spatial_resolution_mm", "mei_px2", "mei_W_mm2",
                       "strain_spatial_resolution_px", "strain_mei_px")
STRAIN_CRITERIA = ("p95_abs_strain_error", "rms_strain_bias", "median_strain_noise", "strain_noise_floor")


def criteria_for(engine: str) -> dict:
    """The ranking criteria of an engine: the stereo ones for pyvale3d, else the 2-D ones."""
    return STEREO_CRITERIA if engine == STEREO else CRITERIA


def smaller_is_better(by: str) -> bool:
    return {**CRITERIA, **STEREO_CRITERIA}[by][2]


@dataclass(frozen=True)
class DicSetting:
    """One DIC setting: subset size and step (px) and the shape function; with a strain window
    (subset centres a side) pyvale's strain too, by its window element and formulation."""
    subset_size: int
    subset_step: int
    shape_function: str
    strain_window: int | None = None
    strain_element: int = 9
    strain_formulation: str = "HENCKY"

    @property
    def name(self) -> str:
        base = f"s{self.subset_size}-st{self.subset_step}-{self.shape_function}"
        if self.strain_window is None:   # without strain: the names (and row keys) as before
            return base
        return f"{base}-sw{self.strain_window}-q{self.strain_element}-{self.strain_formulation.lower()}"

    @property
    def strain(self) -> dict | None:
        """pyvale.strain.calculate_2d's arguments, or None without strain."""
        if self.strain_window is None:
            return None
        return {"window_size": self.strain_window, "window_element": self.strain_element,
                "strain_formulation": self.strain_formulation}


@dataclass(frozen=True)
class Resolution:
    """The sinusoid sweep: periods and amplitude of u(x) = A·sin(2πx/p), px at the plate."""
    periods_px: tuple[float, ...]
    amplitude_px: float


@dataclass(frozen=True)
class Design:
    """A checked design spec: the set-ups (a library :class:`LibraryPlan`), DIC settings, realisations."""
    plan: LibraryPlan
    camera: str
    step: int
    engine: str
    roi_margin: int
    settings: tuple[DicSetting, ...]
    noise_seeds: tuple[int, ...]
    speckle_seeds: tuple[int | None, ...]    # None: the set-up's own speckle.seed
    rig: str
    rank_by: str
    source: dict
    resolution: Resolution | None = None
    cameras: tuple[str, ...] = ()            # the stereo pair (engine pyvale3d), camera 0 first
    calibration: CalibrationSpec = CalibrationSpec()   # the rig the stereo engine measures with

    @property
    def stereo(self) -> bool:
        return self.engine == STEREO

    @property
    def n_rows(self) -> int:
        return len(self.plan.variants) * len(self.settings) * len(self.noise_seeds) * len(self.speckle_seeds)


def _fail(key: str, problem: str, fix: str):
    raise SpecError(f"{key}: {problem} — {fix}")


def _unknown(key: str, got, allowed) -> None:
    extra = sorted(set(got) - set(allowed))
    if extra:
        close = difflib.get_close_matches(extra[0], allowed, 1)
        _fail(f"{key}{extra[0]}", "unknown key", (f"did you mean {close[0]!r}? " if close else "")
              + f"allowed: {', '.join(allowed)}")


def _int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _list(table: dict, key: str, where: str, check, fix: str, default=None) -> tuple:
    value = table.get(key, default)
    if value is None:
        _fail(f"{where}.{key}", "is required", fix)
    values = value if isinstance(value, list) else [value]
    if not values:
        _fail(f"{where}.{key}", "is an empty list", fix)
    if len(values) > MAX_VALUES:
        _fail(f"{where}.{key}", f"has {len(values)} values, more than {MAX_VALUES}", "give fewer")
    for v in values:
        if not check(v):
            _fail(f"{where}.{key}", f"{v!r} is not allowed", fix)
    if len(set(map(json.dumps, values))) != len(values):
        _fail(f"{where}.{key}", f"{values} repeats a value", "list each value once")
    return tuple(values)


def _table(spec: dict, key: str, allowed) -> dict:
    t = spec.get(key, {})
    if not isinstance(t, dict):
        _fail(key, f"expected a table, got {t!r}", f"write [{key}]")
    _unknown(f"{key}.", t, allowed)
    return t


def check_design(spec: dict, spec_dir: str | Path = ".") -> Design:
    """Check a design spec table and expand its set-ups; raises SpecError naming the key."""
    _unknown("", spec, TOP_KEYS)
    engine = spec.get("engine", "quick")
    if engine not in ENGINES:
        _fail("engine", f"{engine!r} is not one of {ENGINES}", "quick: the a-priori noise map only; pyvale2d: "
              "also pyvale's 2-D DIC; pyvale3d: pyvale's stereo DIC (both need .venv-verify: make "
              ".venv-verify/.pyvale-installed)")
    _check_camera_keys(spec, engine)
    margin = spec.get("roi_margin", 4)
    if not (_int(margin) and 0 <= margin <= 1000):
        _fail("roi_margin", f"expected an integer 0…1000 px, got {margin!r}", "write roi_margin = 4")
    dic = _table(spec, "dic", DIC_KEYS)
    sizes = _list(dic, "subset_size", "dic", lambda v: _int(v) and 5 <= v <= MAX_SUBSET and v % 2 == 1,
                  f"give odd subset sizes 5…{MAX_SUBSET} px, e.g. subset_size = [21, 31]")
    steps = _list(dic, "subset_step", "dic", lambda v: _int(v) and 1 <= v <= 1000,
                  "give subset steps of 1…1000 px, e.g. subset_step = 10", default=10)
    shapes = _list(dic, "shape_function", "dic", lambda v: v in SHAPES, f"one or more of {SHAPES}",
                   default="affine")
    settings = tuple(DicSetting(a, b, c, *st) for a, b, c, st in itertools.product(sizes, steps, shapes,
                                                                                  _strain(dic, engine)))
    real = _table(spec, "realisations", REAL_KEYS)
    seed_ok = lambda v: _int(v) and 0 <= v < 2 ** 32   # noqa: E731 (glsim's seeds are uint32 words)
    noise_seeds = _list(real, "noise_seeds", "realisations", seed_ok, "give seeds 0…2³²−1, e.g. noise_seeds = "
                        "[1, 2, 3]", default=[0])
    # without speckle_seeds each set-up keeps its own scene's pattern (None)
    speckle_seeds = _list(real, "speckle_seeds", "realisations", seed_ok, "give seeds 0…2³²−1, e.g. "
                          "speckle_seeds = [0]") if "speckle_seeds" in real else (None,)
    calibration = calibration_spec(spec.get("calibration"))
    rig = calibration.rig
    if rig != "exact" and engine != STEREO:
        _fail("calibration.rig", f"{rig!r} calibrates a stereo rig, and engine is {engine!r}",
              "write engine = \"pyvale3d\" (stereo), or rig = \"exact\" (a 2-D DIC in px needs no calibration)")
    resolution = _resolution(spec, engine, sizes, steps)
    rank = _table(spec, "rank", ("by",))
    criteria = criteria_for(engine)
    by = rank.get("by", "quick_sigma_px" if engine == "quick" else "p95_abs_error_mm" if engine == STEREO
                  else "p95_abs_error_px")
    if by not in criteria:
        if engine == STEREO and by in CRITERIA:
            _fail("rank.by", f"{by!r} is a 2-D criterion, and engine is \"pyvale3d\" (stereo, mm)",
                  "one of " + ", ".join(criteria))
        if engine != STEREO and by in STEREO_CRITERIA:
            _fail("rank.by", f"{by!r} is a stereo criterion, and engine is {engine!r}",
                  "write engine = \"pyvale3d\" (two cameras), or rank by one of " + ", ".join(criteria))
        _fail("rank.by", f"{by!r} is not a criterion", "one of " + ", ".join(criteria))
    if criteria[by][1] and engine == "quick":
        _fail("rank.by", f"{by!r} needs a measuring engine, and engine is \"quick\"",
              "write engine = \"pyvale2d\", or rank by quick_sigma_px or quick_sigma_mm")
    if by in RESOLUTION_CRITERIA and resolution is None:
        _fail("rank.by", f"{by!r} needs the sinusoid sweep", "add a [resolution] table (periods_px, amplitude_px)")
    if by.startswith("strain_") and by in RESOLUTION_CRITERIA and all(st.strain_window is None for st in settings):
        _fail("rank.by", f"{by!r} ranks by the strain's resolution, and [dic] asks for no strain",
              "add dic.strain_window = [5, 9]")
    if by in STRAIN_CRITERIA and all(st.strain_window is None for st in settings):
        _fail("rank.by", f"{by!r} ranks by strain, and [dic] asks for none", "add dic.strain_window = [5, 9]")

    lib = {k: spec[k] for k in ("scene", "seed", "mode", "n", "vary") if k in spec}
    lib["truth"] = False
    if "camera" in spec:
        cam = spec["camera"]
        if not (isinstance(cam, str) or _int(cam)):
            _fail("camera", f"expected a camera name or index, got {cam!r}", 'write camera = "cam0"')
        lib["cameras"] = [cam]
    if "cameras" in spec:
        lib["cameras"] = list(spec["cameras"])
    plan = expand(lib, spec_dir)
    for v in plan.variants:
        names = [c.name for c in v.scene.cameras]
        if len(names) != len(plan.variants[0].scene.cameras) or names != [c.name for c in plan.variants[0].scene.cameras]:
            _fail("vary", f"variant {v.id} has cameras {names}", "vary camera settings, not the cameras' names")
    cameras = _stereo_pair(plan, engine) if engine == STEREO else ()
    camera = cameras[0] if cameras else plan.cameras[0] if "camera" in spec else \
        plan.variants[0].scene.cameras[0].name
    n_steps = next(iter(plan.meshes.values())).n_steps
    step = spec.get("step", n_steps - 1)
    for m in plan.meshes.values():
        if not (_int(step) and 1 <= step < m.n_steps):
            _fail("step", f"{step!r} is not a deformed load step of the specimen (steps 1…{m.n_steps - 1})"
                  if m.n_steps > 1 else "the specimen has only its undeformed step 0",
                  "give the specimen a load step (e.g. [specimen.plate] translations) and step = 1")
    for v in plan.variants:
        for s in settings:
            for c in cameras or (camera,):
                W, H = v.scene.camera(c).size
                if s.subset_size > min(W, H):
                    _fail("dic.subset_size", f"{s.subset_size} px is larger than the image of {c} ({W}×{H}, "
                          f"variant {v.id})", "give smaller subsets")
    # pyvale's DIC writes empty results on small images (the stereo sweep's calculate_3d runs on camera 0's)
    if engine == "pyvale2d" or (engine == STEREO and resolution is not None):
        for v in plan.variants:
            W, H = v.scene.camera(camera).size
            if min(W, H) < 256:
                _fail(f"cameras.{camera}.size", f"{W}×{H} (variant {v.id}) is too small for pyvale's calculate_2d, "
                      "which writes empty results below about 256 px a side", "give at least 256 × 256 px")
    return Design(plan=plan, camera=camera, step=step, engine=engine, roi_margin=margin, settings=settings,
                  noise_seeds=tuple(noise_seeds), speckle_seeds=tuple(speckle_seeds), rig=rig, rank_by=by,
                  source=spec, resolution=resolution, cameras=cameras, calibration=calibration)


def _strain(dic: dict, engine: str) -> list[tuple]:
    """The strain settings of [dic]: (window, element, formulation) combinations, or [()] without
    strain_window (the settings as before)."""
    given = [k for k in STRAIN_KEYS if k in dic]
    if not given:
        return [()]
    if "strain_window" not in dic:
        _fail(f"dic.{given[0]}", "sets pyvale's strain, and dic.strain_window is not given",
              "add strain_window = [5, 9] (the strain window in subset centres a side, odd), or leave it out")
    if engine == "quick":
        _fail("dic.strain_window", "strain is computed by a measuring engine, and engine is \"quick\"",
              "write engine = \"pyvale2d\" (or \"pyvale3d\"), or leave the strain keys out")
    windows = _list(dic, "strain_window", "dic", lambda v: _int(v) and 3 <= v <= MAX_STRAIN_WINDOW and v % 2 == 1,
                    f"give odd windows 3…{MAX_STRAIN_WINDOW} (subset centres a side), e.g. strain_window = [5, 9]")
    elements = _list(dic, "strain_element", "dic", lambda v: _int(v) and v in STRAIN_ELEMENTS,
                     "4 (bilinear) or 9 (biquadratic), e.g. strain_element = 9", default=9)
    forms = _list(dic, "strain_formulation", "dic", lambda v: v in STRAIN_FORMULATIONS,
                  f"one or more of {', '.join(STRAIN_FORMULATIONS)} (pyvale's names)", default="HENCKY")
    return list(itertools.product(windows, elements, forms))


def _check_camera_keys(spec: dict, engine: str) -> None:
    """``camera`` names the 2-D DIC's camera, ``cameras`` the stereo pair: each with its engine."""
    if engine == STEREO and "camera" in spec:
        _fail("camera", "engine pyvale3d measures a stereo pair, not one camera",
              'write cameras = ["cam0", "cam1"] (default: the scene\'s first two), or engine = "pyvale2d"')
    if "cameras" not in spec:
        return
    if engine != STEREO:
        _fail("cameras", f"the stereo pair is for engine = \"pyvale3d\", and engine is {engine!r}",
              'write camera = "cam0" for one camera, or engine = "pyvale3d"')
    cams = spec["cameras"]
    if not (isinstance(cams, list) and len(cams) == 2 and all(isinstance(c, str) or _int(c) for c in cams)):
        _fail("cameras", f"expected two camera names or indices, got {cams!r}", 'write cameras = ["cam0", "cam1"]')
    if cams[0] == cams[1]:
        _fail("cameras", f"{cams} names one camera twice", "give two different cameras")


def _stereo_pair(plan: LibraryPlan, engine: str) -> tuple[str, str]:
    """The stereo pair: ``cameras``, or the scene's first two; each in pyvale's lens model."""
    scene = plan.variants[0].scene
    if len(plan.cameras) < 2:
        _fail("engine", f"pyvale3d needs two cameras, and the scene has one ({scene.cameras[0].name})",
              "add a second [[scene.cameras]] with a stereo pose (examples/bulge.toml), or write engine = \"pyvale2d\"")
    pair = (plan.cameras[0], plan.cameras[1])
    for v in plan.variants:
        for c in pair:
            k = v.scene.camera(c).distortion.coeffs
            if any(k[5:]):
                _fail(f"cameras.{c}.distortion", f"k4…k6 and s1…s4 are {list(k[5:])} (variant {v.id}); pyvale's "
                      "stereo calibration models only k1, k2, p1, p2, k3", "set the others to 0")
    return pair


def default_periods(sizes, steps) -> tuple[float, ...]:
    """Seven periods, geometric, from the smallest subset size (at least 2.5 subset steps, above the
    subset grid's Nyquist period) to eight times the largest (px)."""
    lo, hi = max(float(min(sizes)), 2.5 * max(steps)), 8.0 * float(max(sizes))
    return tuple(round(lo * (hi / lo) ** (k / 6), 1) for k in range(7))


def _resolution(spec: dict, engine: str, sizes, steps) -> Resolution | None:
    if "resolution" not in spec:
        return None
    res = _table(spec, "resolution", RES_KEYS)
    if engine == "quick":
        _fail("resolution", "the sinusoid sweep needs a measuring engine, and engine is \"quick\"",
              "write engine = \"pyvale2d\", or leave [resolution] out")
    num = lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)  # noqa: E731
    periods = _list(res, "periods_px", "resolution", lambda v: num(v) and MIN_PERIOD_PX <= v <= MAX_PERIOD_PX,
                    f"give periods of {MIN_PERIOD_PX:g}…{MAX_PERIOD_PX:g} px, e.g. periods_px = [16, 32, 64, 128]",
                    default=list(default_periods(sizes, steps)))
    if len(periods) < 2:
        _fail("resolution.periods_px", f"{list(periods)} has one period", "give at least two, around the "
              "resolution expected (a few times the subset size)")
    step = max(sz for sz in steps)
    if min(periods) <= 2 * step:
        _fail("resolution.periods_px", f"{min(periods):g} px is not above twice the subset step ({step} px): the "
              "subset grid cannot sample it", f"give periods above {2 * step} px, or a smaller dic.subset_step")
    amp = res.get("amplitude_px", 0.5)
    if not (num(amp) and 0 < amp <= MAX_AMPLITUDE_PX):
        _fail("resolution.amplitude_px", f"expected a number in (0, {MAX_AMPLITUDE_PX:g}] px, got {amp!r}",
              "write amplitude_px = 0.5")
    return Resolution(tuple(sorted(float(p) for p in periods)), float(amp))


def load_design(path: str | Path) -> Design:
    """Read and check a design spec file."""
    spec, spec_dir = read_spec(path)
    return check_design(spec, spec_dir)


def row_key(payload: dict) -> str:
    """The cache key of a row: SHA-256 (first 20 hex digits) of its inputs as sorted JSON."""
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:20]
