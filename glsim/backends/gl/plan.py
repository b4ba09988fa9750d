"""One GL render as data: :func:`plan` turns a request's options, effects and cameras, and what
the driver offers (float64), into the deformation program's #defines, the choices behind them
and the sequence of passes — a pure function, tested without GL; GLBackend executes the plan.

Passes are named by the shader file that ends their program (as ``pass_times`` names them).
Some run only when the view needs them (``when``): ``several`` (pixels with two or more
candidates), ``overflow`` (a list overflowed) and ``big`` (covers over 192 px on a side) are
indirect draws whose instance counts the candidate pass sets on the GPU (0: nothing drawn);
``uncached``: the camera's ray map, made once per camera and supersampling.

The pixel stage: "fragment" runs the exact and q4 modes' pass 2 as full-screen fragment
programs on classify.frag's depth layers (early depth tests, so that each shades only its own
samples: single.frag, resolve.frag) and every full-screen pass as a fragment pass; "compute"
runs pass 2 as compute passes over classify.comp's lists of their pixels, dispatched indirectly
(as many work groups as samples listed: single.comp, resolve.comp), and the box filter, the
image effects and the quantisation as compute passes — each pass's .frag and .comp entry files
share their code (the shaders' .glsl library), the same bytes (tested). Mode fast draws its
triangles in both; in the compute stage that fragment pass (fast_ids.frag) writes only each
sample's triangle and fast_shade.comp shades the samples from the triangles' records.
:func:`pixel_stage` picks the stage per driver.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping, NamedTuple

import numpy as np

from glsim.effects.dof import blur_scheme

PLANS_KEPT = 64   # plans kept by :func:`plan` (one per kind of render; a library makes a few)


@dataclass(frozen=True)
class Pass:
    """A draw or dispatch: its program's last shader file, the condition it runs on (module
    docstring), a variant's name (the blur and PSF passes' #define), the executor's ``step``
    that issues it (GLBackend.STEPS), and for the image passes the frame's textures it reads
    (``inputs``: sampler → texture name) and writes (``outputs``)."""
    shader: str
    when: str = ""
    variant: str = ""
    step: str = ""
    inputs: tuple[tuple[str, str], ...] = ()
    outputs: tuple[str, ...] = ()


@dataclass(frozen=True)
class PassPlan:
    """``defines`` of the deformation program (sorted items); ``rays`` the ray map's kind
    (exact: "bits" float64 pairs, "split" float32 hi + lo made in float64, "float"; else None);
    ``ref`` the reference projection ("REF_PINHOLE" float64 blends, "REF_LOCAL" float32 relative
    records, None the general projection); ``camera_local`` float32 exact relative to each
    element's centre; ``subsamples`` Newton sub-samples; ``stage`` the pixel stage (module
    docstring); ``passes`` in order."""
    defines: tuple[tuple[str, object], ...]
    rays: str | None
    ref: str | None
    camera_local: bool
    subsamples: bool
    stage: str
    passes: tuple[Pass, ...]

    @functools.cached_property
    def define_dict(self) -> Mapping[str, object]:
        """``defines`` as a read-only mapping (made once)."""
        return MappingProxyType(dict(self.defines))

    @functools.cached_property
    def image_effects(self) -> bool:
        """Whether full-screen passes work on the pixels between their integration (the
        deformation pass, the box filter) and quantisation: blur, camera effects, noise."""
        return any(p.shader not in PIXEL_PASSES and p.step != "quantize" for p in self.passes)


class EffectsShape(NamedTuple):
    """What of a render's effects (:class:`glsim.effects.Effects`) its plan depends on:
    ``lights`` how many (None: unlit), ``multiplicative`` how they combine, ``blur`` and its
    ``scheme`` (:func:`~glsim.effects.dof.blur_scheme`), ``aperture`` √(fill factor), whether
    there are ``vignette``, ``fixed_pattern`` and ``noise``, and ``psf``: "separable", "2d" or
    None. Small and hashable, so that plans are made once per shape (:func:`plan`)."""
    lights: int | None = None
    multiplicative: bool = False
    blur: bool = False
    scheme: str | None = None
    aperture: float = 1.0
    vignette: bool = False
    psf: str | None = None
    fixed_pattern: bool = False
    noise: bool = False

    @classmethod
    def of(cls, fx) -> "EffectsShape":
        """The shape of ``fx`` (an Effects, a shape, or None: no effects)."""
        if fx is None:
            return _NO_EFFECTS
        if isinstance(fx, EffectsShape):
            return fx
        lit, blur = fx.lighting, fx.blur
        return cls(None if lit is None else len(lit.lights), lit is not None and lit.combine == "multiplicative",
                   blur, blur_scheme(fx.optics) if blur else None, fx.aperture, fx.vignette is not None,
                   None if fx.psf is None else "separable" if fx.psf.taps is not None else "2d",
                   fx.fixed_pattern, fx.noise is not None)


_NO_EFFECTS = EffectsShape()


def deform_defines(opts, truth: bool, fp64: bool, fx: EffectsShape = _NO_EFFECTS) -> dict:
    """The #defines of the deformation program that follow from the options and effects alone."""
    d = {f"INTERP_{opts.interpolation.upper()}": None, "SS": opts.supersampling}
    if opts.mode != "fast":   # (mode fast's passes are its own entry files)
        d[f"MODE_{opts.mode.upper()}"] = None
    if opts.precision == "fp64" and fp64 and opts.mode != "fast":
        d["FP64"] = None
    if truth:
        d["TRUTH"] = None
        if "FP64" in d:  # (xi, eta) are float64 in the shader: write their low float32 halves too
            d["TRUTH_LO"] = None
    if fx.lights is not None:
        d["LIGHTING"] = None
        d["MAX_LIGHTS"] = max(1, fx.lights)
        if fx.multiplicative:
            d["LIGHT_MULTIPLICATIVE"] = None
    if fx.blur:
        d["DEPTH_OUT"] = None
        d["DEPTH_LOCATION"] = 1 + 2 * truth + ("TRUTH_LO" in d)
    if fx.aperture != 1.0 and opts.supersampling > 1:   # (one sample: the pixel centre)
        d["APERTURE"] = aperture_literal(fx.aperture, "FP64" in d)
    return d


def aperture_literal(aperture: float, fp64: bool) -> str:
    """√(sensor.fill_factor) as a GLSL expression of type ``real`` (shaders/camera.glsl's
    aperture_sample): for float64 programs its bits (``packDouble2x32``), since NVIDIA's compiler
    reads decimal double literals up to an ulp off (0.1lf as 0.09999999999999999 on an H100:
    README, "glsim check"); for float32 ones the value's shortest repr."""
    if not fp64:
        return repr(float(aperture))
    lo, hi = np.array([aperture], "<f8").view("<u4")
    return f"packDouble2x32(uvec2({int(lo):#010x}u, {int(hi):#010x}u))"


def newton_subsamples(opts, s: int, quadratic: bool) -> bool:
    """Whether the sub-samples of single-candidate pixels are placed by Newton steps from their
    pixel centre (shaders/subsamples.frag, which then replaces the box filter)."""
    return opts.subsamples == "newton" and opts.mode == "exact" and s > 1 and not quadratic


# the passes that integrate the pixels (the deformation pass's, the box filter)
PIXEL_PASSES = {"rays.frag", "view.comp", "candidates.comp", "candidates.frag", "classify.frag", "subsamples.frag",
                "fast.frag", "fast_ids.frag", "fast_shade.comp", "single.frag", "resolve.frag", "overflow.frag",
                "classify.comp", "single.comp", "resolve.comp", "downsample.frag", "downsample.comp"}
PIXEL_STAGES = ("fragment", "compute")


def environment_stage() -> str | None:
    """The pixel stage the environment asks for (GLSIM_PIXEL_STAGE: "fragment" or "compute", to
    compare the two on a driver or to step around one's fault), or None; a value that is neither
    is refused (the CLI checks it before any command writes)."""
    import os

    from glsim.errors import SceneError

    value = os.environ.get("GLSIM_PIXEL_STAGE", "").strip()
    if value and value not in PIXEL_STAGES:
        raise SceneError("environment variable GLSIM_PIXEL_STAGE", f"{value!r} is not a pixel stage",
                         f"set it to one of {', '.join(PIXEL_STAGES)}, or unset it for the driver's")
    return value or None


def pixel_stage(software: bool) -> str:
    """The pixel stage for a driver: "fragment" on a software rasterizer (llvmpipe runs neither
    stage faster throughout: the throughput table's other-stage column), "compute" on a GPU:
    data-centre GPUs (H100, H200) run fragment shaders on a few of their SMs only (NVIDIA's
    Hopper whitepaper: two of the H100's TPCs are graphics-capable), and the H100 ran its float64
    deformation pass, a fragment pass, at a far smaller multiple of llvmpipe's speed than its
    compute passes (the throughput tables' pass columns; README "What is not here yet")."""
    return "fragment" if software else "compute"

# the depth-of-field passes of each scheme (glsim.effects.dof.blur_scheme), in order
BLUR_PASSES = {"disk": ("BLUR_DISK",), "gather": ("BLUR_GATHER",), "expansion": ("BLUR_ROWS", "BLUR_COLUMNS"),
               "separable": ("BLUR_HORIZONTAL", "BLUR_VERTICAL"), "hybrid": ("BLUR_HORIZONTAL", "BLUR_HYBRID")}
# each blur pass's samplers → the frame's textures they read (all read u_depth), and what it writes
_BLUR_IO = {"BLUR_DISK": ({"u_src": "grey"}, ("grey",)), "BLUR_GATHER": ({"u_src": "grey"}, ("grey",)),
            "BLUR_HORIZONTAL": ({"u_src": "grey"}, ("rows",)), "BLUR_VERTICAL": ({"u_src": "rows"}, ("grey",)),
            "BLUR_HYBRID": ({"u_src": "rows", "u_image": "grey"}, ("grey",)),
            "BLUR_ROWS": ({"u_src": "grey"}, ("moments", "rows")),
            "BLUR_COLUMNS": ({"u_image": "grey", "u_moments": "moments", "u_rows": "rows"}, ("grey",))}


def blur_passes(scheme: str, ext: str = "frag") -> list[Pass]:
    """The depth-of-field passes of ``scheme`` (in the pixel stage of ``ext``)."""
    return [Pass(f"blur.{ext}", "", name, "blur", (*_BLUR_IO[name][0].items(), ("u_depth", "depth")),
                 _BLUR_IO[name][1]) for name in BLUR_PASSES[scheme]]


def _image_pass(shader: str, variant: str = "") -> Pass:
    """A camera or noise pass: grey in, grey out."""
    return Pass(shader, "", variant, shader.split(".")[0], (("u_src", "grey"),), ("grey",))


def plan(opts, truth: bool, fp64_driver: bool, fx, camera, ref_camera, pieces: int | None = None,
         stage: str = "fragment", quantize: bool = False) -> PassPlan:
    """The plan of one render at ``opts.supersampling`` (the deformation program writes the
    truth maps only at 1 spp): ``opts`` the [render] options, ``truth`` whether the pixel-centre
    raster is asked for, ``fp64_driver`` whether the driver has GL_ARB_gpu_shader_fp64, ``fx`` the
    effects (or None), the view's and the reference's cameras, ``pieces`` the pieces per side of
    curved elements (exact, q4) or None, ``stage`` the pixel stage (module docstring),
    ``quantize`` whether the image is quantised on the GPU (its last pass). With
    truth at s > 1 the executor runs the plan of the same render at 1 spp for it. Made once per distinct argument (:func:`_plan` sees only what
    a plan depends on, so a kept plan cannot go stale)."""
    return _plan(opts, truth, fp64_driver, EffectsShape.of(fx), camera.distortion.is_zero,
                 ref_camera.distortion.is_zero, pieces, stage, quantize)


@functools.lru_cache(maxsize=PLANS_KEPT)
def _plan(opts, truth: bool, fp64_driver: bool, fx: EffectsShape, pinhole: bool, ref_pinhole: bool,
          pieces: int | None, stage: str, quantize: bool) -> PassPlan:
    """:func:`plan` over its dependencies: ``pinhole`` / ``ref_pinhole`` whether the view's /
    the reference camera's distortion is zero."""
    s = opts.supersampling
    d = deform_defines(opts, truth and s == 1, fp64_driver, fx)
    if pieces is not None:
        d.update(QUADRATIC=None, PIECES=int(pieces))
    fp64 = "FP64" in d
    # exact with a pinhole reference camera (a distorted one keeps the direct projection): float32
    # projects relative to each element's centre, float64 from per-element blends
    pinhole_ref = opts.mode == "exact" and pieces is None and ref_pinhole
    ref = ("REF_PINHOLE" if fp64 else "REF_LOCAL") if pinhole_ref else None
    if ref:
        d[ref] = None
    # float32 exact on a driver with float64: the per-element and per-camera work (records, ray
    # map) in float64, the per-sample work in float32 relative to each element's centre
    camera_local = ref == "REF_LOCAL" and fp64_driver
    if camera_local:
        d["CAMERA_LOCAL"] = None
    if opts.mode == "exact" and pieces is None and pinhole:
        d["PIXEL_TIES"] = None   # ties decided at the exact pixel point (bilinear.glsl)
    rays = ("bits" if fp64 else "split" if camera_local else "float") if opts.mode == "exact" else None
    sub = newton_subsamples(opts, s, pieces is not None)
    blur = fx.blur
    comp = stage == "compute"
    ext = "comp" if comp else "frag"   # the full-screen passes' in either stage
    passes: list[Pass] = []
    if opts.mode == "fast":   # the element triangles (compute: their indices only, then shaded)
        passes += ([Pass("fast_ids.frag", step="fast_ids"), Pass("fast_shade.comp", step="fast_shade")] if comp
                   else [Pass("fast.frag", step="fast")])
    else:
        if rays:
            passes.append(Pass("rays.frag", "uncached", step="rays"))
        passes += [Pass("view.comp", step="view"), Pass("candidates.comp", step="candidates"),
                   Pass("candidates.frag", "big", step="big_covers")]
        if sub:
            passes += [Pass("classify.frag", step="newton_layers"), Pass("rays.frag", "uncached", step="centre_rays"),
                       Pass("subsamples.frag", step="newton")]
        if comp:
            passes += [Pass("classify.comp", step="pixel_lists"), Pass("single.comp", step="listed"),
                       Pass("resolve.comp", "several", step="listed")]
        else:
            passes += [Pass("classify.frag", step="layers"), Pass("single.frag", step="layer"),
                       Pass("resolve.frag", "several", step="layer")]
        passes.append(Pass("overflow.frag", "overflow", step="overflow"))
    if s > 1:   # grey, and the covered samples' mean depth
        passes.append(Pass(f"downsample.{ext}", step="box", inputs=(("u_samples", "samples"),), outputs=("grey",)))
        if blur:
            passes.append(Pass(f"downsample.{ext}", variant="COVERED_MEAN", step="box",
                               inputs=(("u_samples", "sample_depth"),), outputs=("depth",)))
    if blur:
        passes += blur_passes(fx.scheme, ext)
    if fx.vignette:
        passes.append(_image_pass(f"vignette.{ext}"))
    if fx.psf is not None:
        passes += [_image_pass(f"psf.{ext}", v) for v in (("PSF_ROWS", "PSF_COLUMNS") if fx.psf == "separable"
                                                           else ("PSF_2D",))]
    if fx.fixed_pattern:
        passes.append(_image_pass(f"fpn.{ext}"))
    if fx.noise:
        passes.append(_image_pass(f"noise.{ext}"))
    if quantize:
        passes.append(Pass(f"quantize.{ext}", step="quantize", inputs=(("u_src", "grey"),), outputs=("grey",)))
    return PassPlan(tuple(sorted(d.items())), rays, ref, camera_local, sub, stage, tuple(passes))
