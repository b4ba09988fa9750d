"""One GL render as data: :func:`plan` turns a request's options, effects and cameras, and what
the driver offers (float64), into the deformation program's #defines, the choices behind them
and the sequence of passes — a pure function, tested without GL; GLBackend executes the plan.

Passes are named by the shader file that ends their program (as ``pass_times`` names them).
Some run only when the view needs them (``when``): ``several`` (pixels with two or more
candidates), ``overflow`` (a list overflowed) and ``big`` (covers over 192 px on a side) are
indirect draws whose instance counts the candidate pass sets on the GPU (0: nothing drawn);
``uncached``: the camera's ray map, made once per camera and supersampling.
"""
from __future__ import annotations

from dataclasses import dataclass

from glsim.effects.dof import blur_scheme


@dataclass(frozen=True)
class Pass:
    """A draw or dispatch: its program's last shader file, the condition it runs on (module
    docstring), and a variant's name (the blur pass's #define)."""
    shader: str
    when: str = ""
    variant: str = ""


@dataclass(frozen=True)
class Plan:
    """``defines`` of the deformation program (sorted items); ``rays`` the ray map's kind
    (exact: "bits" float64 pairs, "split" float32 hi + lo made in float64, "float"; else None);
    ``ref`` the reference projection ("REF_PINHOLE" float64 blends, "REF_LOCAL" float32 relative
    records, None the general projection); ``camera_local`` float32 exact relative to each
    element's centre; ``subsamples`` Newton sub-samples; ``passes`` in order."""
    defines: tuple[tuple[str, object], ...]
    rays: str | None
    ref: str | None
    camera_local: bool
    subsamples: bool
    passes: tuple[Pass, ...]

    @property
    def define_dict(self) -> dict:
        return dict(self.defines)


def deform_defines(opts, truth: bool, fp64: bool, fx=None) -> dict:
    """The #defines of the deformation program that follow from the options and effects alone."""
    d = {f"MODE_{opts.mode.upper()}": None, f"INTERP_{opts.interpolation.upper()}": None,
         "SS": opts.supersampling}
    if opts.precision == "fp64" and fp64 and opts.mode != "fast":
        d["FP64"] = None
    if truth:
        d["TRUTH"] = None
        if "FP64" in d:  # (xi, eta) are float64 in the shader: write their low float32 halves too
            d["TRUTH_LO"] = None
    if fx is not None and fx.lighting is not None:
        d["LIGHTING"] = None
        d["MAX_LIGHTS"] = max(1, len(fx.lighting.lights))
        if fx.lighting.combine == "multiplicative":
            d["LIGHT_MULTIPLICATIVE"] = None
    if fx is not None and fx.blur:
        d["DEPTH_OUT"] = None
        d["DEPTH_LOCATION"] = 1 + 2 * truth + ("TRUTH_LO" in d)
    if fx is not None and fx.aperture != 1.0 and opts.supersampling > 1:   # (one sample: the pixel centre)
        d["APERTURE"] = aperture_literal(fx.aperture, "FP64" in d)
    return d


def aperture_literal(aperture: float, fp64: bool) -> str:
    """√(sensor.fill_factor) as a GLSL literal of type ``real`` (shaders/camera.glsl's
    aperture_sample): the float64 value's shortest repr, with ``lf`` for float64 programs."""
    return repr(float(aperture)) + ("lf" if fp64 else "")


def newton_subsamples(opts, s: int, quadratic: bool) -> bool:
    """Whether the sub-samples of single-candidate pixels are placed by Newton steps from their
    pixel centre (shaders/subsamples.frag, which then replaces the box filter)."""
    return opts.subsamples == "newton" and opts.mode == "exact" and s > 1 and not quadratic


# the depth-of-field passes of each scheme (glsim.effects.dof.blur_scheme), in order
BLUR_PASSES = {"disk": ("BLUR_DISK",), "gather": ("BLUR_GATHER",), "expansion": ("BLUR_ROWS", "BLUR_COLUMNS"),
               "separable": ("BLUR_HORIZONTAL", "BLUR_VERTICAL"), "hybrid": ("BLUR_HORIZONTAL", "BLUR_HYBRID")}


def plan(opts, truth: bool, fp64_driver: bool, fx, camera, ref_camera, pieces: int | None = None) -> Plan:
    """The plan of one render at ``opts.supersampling`` (the deformation program writes the
    truth maps only at 1 spp): ``opts`` the [render] options, ``truth`` whether the pixel-centre
    raster is asked for, ``fp64_driver`` whether the driver has GL_ARB_gpu_shader_fp64, ``fx`` the
    effects (or None), the view's and the reference's cameras, ``pieces`` the pieces per side of
    curved elements (exact, q4) or None. With truth at s > 1 the executor runs the plan of the
    same render at 1 spp for it."""
    s = opts.supersampling
    d = deform_defines(opts, truth and s == 1, fp64_driver, fx)
    if pieces is not None:
        d.update(QUADRATIC=None, PIECES=int(pieces))
    fp64 = "FP64" in d
    # exact with a pinhole reference camera (a distorted one keeps the direct projection): float32
    # projects relative to each element's centre, float64 from per-element blends
    pinhole_ref = opts.mode == "exact" and pieces is None and ref_camera.distortion.is_zero
    ref = ("REF_PINHOLE" if fp64 else "REF_LOCAL") if pinhole_ref else None
    if ref:
        d[ref] = None
    # float32 exact on a driver with float64: the per-element and per-camera work (records, ray
    # map) in float64, the per-sample work in float32 relative to each element's centre
    camera_local = ref == "REF_LOCAL" and fp64_driver
    if camera_local:
        d["CAMERA_LOCAL"] = None
    if opts.mode == "exact" and pieces is None and camera.distortion.is_zero:
        d["PIXEL_TIES"] = None   # ties decided at the exact pixel point (bilinear.glsl)
    rays = ("bits" if fp64 else "split" if camera_local else "float") if opts.mode == "exact" else None
    sub = newton_subsamples(opts, s, pieces is not None)
    blur = fx is not None and fx.blur
    passes: list[Pass] = []
    if opts.mode == "fast":
        passes.append(Pass("deform.frag"))   # deform.vert, fast.geom: the element triangles
    else:
        if rays:
            passes.append(Pass("rays.frag", "uncached"))
        passes += [Pass("view.comp"), Pass("candidates.comp"), Pass("candidates.frag", "big")]
        if sub:
            passes += [Pass("classify.frag"), Pass("rays.frag", "uncached"), Pass("subsamples.frag")]
        passes += [Pass("classify.frag"), Pass("deform.frag"), Pass("resolve.frag", "several"),
                   Pass("deform.frag", "overflow")]
    if s > 1:
        passes += [Pass("downsample.frag")] * (1 + blur)   # grey, and the covered samples' mean depth
    if blur:
        passes += [Pass("blur.frag", "", name) for name in BLUR_PASSES[blur_scheme(fx.optics)]]
    if fx is not None and fx.vignette is not None:
        passes.append(Pass("vignette.frag"))
    if fx is not None and fx.psf is not None:
        passes += [Pass("psf.frag", "", v) for v in (("PSF_ROWS", "PSF_COLUMNS") if fx.psf.taps is not None
                                                       else ("PSF_2D",))]
    if fx is not None and fx.fixed_pattern:
        passes.append(Pass("fpn.frag"))
    if fx is not None and fx.noise is not None:
        passes.append(Pass("noise.frag"))
    return Plan(tuple(sorted(d.items())), rays, ref, camera_local, sub, tuple(passes))
