"""The GL render plan (glsim.backends.gl.plan) without GL: the #defines and passes follow from
the request alone; and with GL: the passes a render executes are the plan's, in its order."""
import dataclasses

import numpy as np
import pytest

from glsim.backends.gl.plan import plan
from glsim.effects import Effects, prepare as prepare_effects
from glsim.io.fe import specimen_mesh
from glsim.render import Renderer
from glsim.scene import Render, bulge_scene, demo_effects
from glsim.scene.camera import Camera, Distortion

PIN = Camera(name="c", size=(64, 48), fx=800.0, fy=800.0, cx=31.5, cy=23.5)
BARREL = dataclasses.replace(PIN, distortion=Distortion(k1=-0.1))


def shaders(p):
    return [x.shader for x in p.passes]


def test_exact_float64_plan():
    p = plan(Render(mode="exact"), True, True, None, PIN, PIN)
    d = p.define_dict
    assert {"MODE_EXACT", "FP64", "TRUTH", "TRUTH_LO", "REF_PINHOLE", "PIXEL_TIES"} <= set(d) and d["SS"] == 1
    assert p.rays == "bits" and p.ref == "REF_PINHOLE" and not p.camera_local and not p.subsamples
    assert shaders(p) == ["rays.frag", "view.comp", "candidates.comp", "candidates.frag", "classify.frag",
                          "single.frag", "resolve.frag", "overflow.frag"]
    assert [x.when for x in p.passes if x.when] == ["uncached", "big", "several", "overflow"]


def test_float32_exact_and_drivers_without_float64():
    p = plan(Render(mode="exact", precision="fp32"), False, True, None, BARREL, PIN)
    assert "FP64" not in p.define_dict and {"REF_LOCAL", "CAMERA_LOCAL"} <= set(p.define_dict)
    assert p.rays == "split" and "PIXEL_TIES" not in p.define_dict       # a distorted view camera
    q = plan(Render(mode="exact"), False, False, None, PIN, BARREL)      # no fp64, distorted reference
    assert q.rays == "float" and q.ref is None and "FP64" not in q.define_dict


def test_fast_q4_and_curved_plans():
    fast = plan(Render(mode="fast", samples_per_pixel=4), True, True, None, PIN, PIN)
    assert shaders(fast) == ["fast.frag", "downsample.frag"] and "FP64" not in fast.define_dict
    assert "TRUTH" not in fast.define_dict      # truth maps only at 1 spp (a second render)
    q4 = plan(Render(mode="q4"), False, True, None, PIN, PIN, pieces=4)
    assert {"MODE_Q4", "FP64", "QUADRATIC"} <= set(q4.define_dict) and q4.define_dict["PIECES"] == 4
    assert q4.rays is None and q4.ref is None and "rays.frag" not in shaders(q4)


def test_effects_add_their_passes_only():
    scene = demo_effects(bulge_scene(size=(406, 308), steps=1))
    pitch = 30.0 / (6818.0 * 406 / 1624)   # the rig's pixel pitch for its 30 mm lens; f/1 defocuses the bulge
    scene = dataclasses.replace(scene, optics=dataclasses.replace(scene.optics, f_number=1.0, pixel_pitch=pitch))
    mesh = specimen_mesh(scene)
    fx = prepare_effects(scene, mesh.deformed(1), mesh.quads, scene.cameras[0], 0, 1, np.array([550.0, 650.0]),
                         normals=False)
    p = plan(Render(mode="exact", samples_per_pixel=4, subsamples="newton"), False, True, fx, PIN, PIN)
    assert {"LIGHTING", "DEPTH_OUT"} <= set(p.define_dict) and p.subsamples
    assert shaders(p)[-5:] == ["downsample.frag", "downsample.frag", "blur.frag", "blur.frag", "noise.frag"]
    assert [x.variant for x in p.passes if x.variant] == ["COVERED_MEAN", "BLUR_ROWS", "BLUR_COLUMNS"]   # "auto": expansion
    assert "subsamples.frag" in shaders(p)
    bare = plan(Render(mode="exact"), False, True, None, PIN, PIN)
    assert not {"LIGHTING", "DEPTH_OUT"} & set(bare.define_dict) and "noise.frag" not in shaders(bare)
    # passes on the pixels between their integration and quantisation
    assert p.image_effects and not bare.image_effects
    quantized = plan(Render(mode="exact"), False, True, None, PIN, PIN, quantize=True)
    assert shaders(quantized)[-1] == "quantize.frag" and not quantized.image_effects
    assert not plan(Render(mode="fast", samples_per_pixel=4), False, True, Effects(aperture=0.5), PIN, PIN).image_effects


@pytest.mark.gl
@pytest.mark.parametrize("stage", ["fragment", "compute"])
@pytest.mark.parametrize("options", [dict(mode="fast"), dict(mode="q4", truth=True, quantize=True),
                                     dict(mode="exact", samples_per_pixel=4, truth=True),
                                     dict(mode="exact", samples_per_pixel=4, subsamples="newton")])
def test_a_render_executes_the_plans_passes_in_order(options, stage, gl_ctx):
    """The passes a render executes are its plan's, in the plan's order (either pixel stage;
    truth at s > 1: then those of the same render's plan at 1 spp, without effects), and pass
    timing names them."""
    scene = demo_effects(bulge_scene(size=(96, 72), steps=1))
    render = {k: v for k, v in options.items() if k not in ("truth", "quantize")}
    truth, quantize = options.get("truth", False), options.get("quantize", False)
    with Renderer(scene, "gl", ctx=gl_ctx) as r:
        r.backend.stage = stage
        r.render(0, 1, **options)
        with r.backend.pass_times() as timed:
            r.render(0, 1, **options)
        ran = r.backend.last_passes
        view = r.geometry.view(scene.cameras[0], 1)
        fx = prepare_effects(scene, view.step_geo.deformed, r.drawn_mesh.quads, scene.cameras[0], 0, 1,
                             view.corner_depths())
        fp64 = r.backend.fp64
    opts = dataclasses.replace(scene.render, **render)
    spp = opts.samples_per_pixel
    p = plan(opts, truth and spp == 1, fp64, fx, scene.cameras[0], r.reference.camera, stage=stage,
             quantize=quantize and fp64)
    want = shaders(p)
    if truth and spp > 1:
        want += shaders(plan(dataclasses.replace(opts, samples_per_pixel=1), True, fp64, None, scene.cameras[0],
                             r.reference.camera, stage=stage))
    assert list(ran) == want
    assert set(timed) == set(want)


def test_the_pixel_stage_is_the_drivers_and_fast_draws_its_triangles_in_both():
    """The plan's passes per stage; the defines are the stage's own business (the same)."""
    from glsim.backends.gl.plan import pixel_stage

    assert pixel_stage(True) == "fragment" and pixel_stage(False) == "compute"
    p = plan(Render(mode="exact", samples_per_pixel=4), True, True, None, PIN, PIN, stage="compute")
    assert p.stage == "compute" and "classify.frag" not in shaders(p)
    assert shaders(p)[-5:] == ["classify.comp", "single.comp", "resolve.comp", "overflow.frag",   # (overflow: covers)
                               "downsample.comp"]
    assert p.define_dict == plan(Render(mode="exact", samples_per_pixel=4), True, True, None, PIN, PIN).define_dict
    fast = plan(Render(mode="fast", samples_per_pixel=4), False, True, None, PIN, PIN, stage="compute")
    assert shaders(fast) == ["fast_ids.frag", "fast_shade.comp", "downsample.comp"]   # (the triangles' indices, then shaded)


@pytest.mark.gl
def test_the_environment_picks_the_pixel_stage(gl_ctx, monkeypatch, tmp_path, capsys):
    """GLSIM_PIXEL_STAGE overrides the driver's stage; a value that is none is refused with the
    variable, the value and the fix named, by the backend and by the CLI before it writes."""
    from pathlib import Path

    from glsim import cli

    EXAMPLES = Path(__file__).parents[1] / "examples"
    from glsim.backends.gl.backend import GLBackend
    from glsim.errors import SceneError

    for stage in ("fragment", "compute"):
        monkeypatch.setenv("GLSIM_PIXEL_STAGE", stage)
        backend = GLBackend(np.zeros((8, 8), np.float32), ctx=gl_ctx)
        assert backend.stage == stage
        backend.close()
    monkeypatch.setenv("GLSIM_PIXEL_STAGE", "vertex")
    message = "GLSIM_PIXEL_STAGE: 'vertex' is not a pixel stage — set it to one of fragment, compute, or unset it"
    with pytest.raises(SceneError, match=message):
        GLBackend(np.zeros((8, 8), np.float32), ctx=gl_ctx)
    out = tmp_path / "out"
    assert cli.main(["render", str(EXAMPLES / "bulge.toml"), "--out", str(out)]) == 2
    assert message in capsys.readouterr().err and not out.exists()   # (no regex metacharacters in it)


@pytest.mark.both_stages
@pytest.mark.gl
def test_the_compute_pixel_stage_gives_the_fragment_stages_bytes(gl_ctx):
    """The compute pixel stage (the default on GPUs: exact and q4's pass 2 over pixel lists,
    fast's samples from its triangles' records, every full-screen pass as a compute pass)
    writes the images, 8- and 12-bit images and truth of the fragment stage (llvmpipe's
    default) bit for bit: every mode, float64 and float32, 1 and 4 samples per pixel (mapped and
    Newton sub-samples), a fill factor, lighting, depth of field, noise, vignetting, a Gaussian
    PSF and fixed-pattern noise, a quadratic mesh (Q8), two cameras and two steps; and its
    renders ran the compute passes."""
    from test_quadratic import scene as q8_scene, surface_mesh

    from glsim.backends.gl.backend import GLBackend

    plain = bulge_scene(size=(128, 96), steps=2)
    lit = demo_effects(plain)   # lit, noisy and defocused: f/1, pixels a quarter of the rig's pitch
    lit = dataclasses.replace(lit, optics=dataclasses.replace(lit.optics, f_number=1.0,
                                                              pixel_pitch=30.0 / 6818.0 / 4))
    twelve = dataclasses.replace(plain, cameras=tuple(dataclasses.replace(c, bit_depth=12) for c in plain.cameras))
    camera = demo_effects(plain).replace(psf={"kind": "gaussian", "sigma": 0.8}, vignetting={"natural": True},
                                         sensor={"prnu": 1.0, "dsnu": 2.0})   # the camera passes too
    options = [{"mode": m, "samples_per_pixel": s} for m in ("exact", "q4", "fast") for s in (1, 4)]
    options += [{"mode": "exact", "samples_per_pixel": 4, "subsamples": "newton"},
                {"mode": "exact", "precision": "fp32"}, {"mode": "q4", "precision": "fp32", "samples_per_pixel": 4}]
    cases = [(plain, None, options, ((0, 1), (1, 1), (0, 2))),
             (plain.replace(sensor={"fill_factor": 0.5}), None, [{"mode": "exact", "samples_per_pixel": 4}], ((0, 1),)),
             (lit, None, options[:6], ((0, 1), (1, 2))),
             (twelve, None, options[:6], ((1, 1),)),
             (camera, None, options[:6], ((0, 1),)),
             (q8_scene(), surface_mesh("quad8"), options[:4], ((0, 1),))]

    def renders(stage):
        out, ran = [], set()
        for scene, mesh, opts, views in cases:
            with Renderer(scene, "gl", ctx=gl_ctx, mesh=mesh) as r:
                assert isinstance(r.backend, GLBackend)
                r.backend.stage = stage
                for o in opts:
                    for cam, step in views:
                        with r.backend.pass_times() as p:
                            res = r.render(cam, step, truth=True, **o)
                            image = r.render(cam, step, quantize=True, **o).image
                        ran |= set(p)
                        out += [res.image, image, res.truth.element, res.truth.xi, res.truth.eta, res.truth.ref_uv]
        return out, ran

    fragment, ran_f = renders("fragment")
    compute, ran_c = renders("compute")
    assert {"classify.comp", "single.comp", "resolve.comp", "downsample.comp", "quantize.comp"} <= ran_c
    assert not {"classify.comp", "single.comp", "resolve.comp", "downsample.comp", "quantize.comp"} & ran_f
    assert "classify.frag" in ran_f and "classify.frag" in ran_c   # (compute: Newton's pixels at 1 spp only)
    assert {"blur.comp", "noise.comp", "vignette.comp", "psf.comp", "fpn.comp"} <= ran_c
    assert not {x for x in ran_c if x.endswith(".frag")} - {"overflow.frag", "classify.frag", "subsamples.frag",
                                                           "rays.frag", "candidates.frag", "fast_ids.frag"}
    assert len(fragment) == len(compute)
    for a, b in zip(fragment, compute):
        np.testing.assert_array_equal(a, b)


@pytest.mark.gl
def test_compute_lists_longer_than_a_row_of_work_groups(gl_ctx):
    """A layer with more samples than one row of indirect work groups holds (65,535 × 64:
    pixellists.glsl) is dispatched as rows of them: the scaling plate at 1624×1234, q4, 4 spp
    (about 1.4 Mpx of single-candidate pixels) gives the fragment stage's bytes."""
    from glsim.bench.scaling import plate_scene

    size = (1624, 1234)
    with Renderer(plate_scene(size, 2000), "gl", ctx=gl_ctx) as r:
        images = []
        for r.backend.stage in ("fragment", "compute"):
            images.append(r.render(0, 0, mode="q4", samples_per_pixel=4, quantize=True).image)
        lists = r.backend.geometry._bufs[("pixel_lists", *size)]
        args = np.frombuffer(lists.read(size=32), np.uint32)
    assert args[6] * 4 > 65_535 * 64 and args[0] == 65_535 and args[1] == 2   # (layer 0: one candidate)
    np.testing.assert_array_equal(images[0], images[1])
