"""The shader loader, the GLSL camera model against OpenCV, and the compile-time choice of
program features."""
import ctypes.util
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from glsim.scene.camera import Camera, Distortion
from glsim.errors import GLUnavailableError, ShaderError
from glsim.backends.gl import context as glctx
from glsim.backends.gl.backend import GLBackend
from glsim.backends.gl.programs import ProgramCache, assemble
from glsim.render import Renderer
from glsim.scene import bulge_scene

GLSL_DIR = Path(__file__).parent / "glsl"


def test_assemble_resolves_includes_once_and_maps_lines():
    src = assemble("single.frag", {"MODE_EXACT": None, "INTERP_LINEAR": None, "SS": 2})
    assert src.text.startswith("#version 450 core\n")
    assert "#define SS 2" in src.text and "#include" not in src.text
    assert src.text.count("real2 distort(real2 xn") == 1       # camera.glsl included once (by several files)
    line = src.text.splitlines().index("void main() {") + 1
    assert src.locate(line).startswith("single.frag:")
    line = next(i for i, t in enumerate(src.text.splitlines(), 1) if t.startswith("bool map_single("))
    assert src.locate(line).startswith("owners.glsl:")


_LOOPS = """#define N 3
void f(inout int x[4]) {
    #pragma unroll
    for (int k = 0; k < N; ++k) {
        x[k] = k;   // a comment
        if (k == 1) continue;
        #pragma unroll
        for (int j = 0; j <= 1; ++j) x[3] += (k + j) * 10;
    }
}
"""


def test_unroll_writes_each_index_out_as_a_constant(tmp_path):
    """#pragma unroll (glsim.backends.gl.programs._unroll): one do { const int k = …; } while
    (false) per index, nested loops too, each line still naming its origin."""
    (tmp_path / "loops.glsl").write_text(_LOOPS)
    src = assemble("loops.glsl", {}, dirs=(tmp_path,))
    body = src.text.split("#define N 3\n")[1]
    assert "for (" not in body and "#pragma" not in body
    assert [int(k) for k in re.findall(r"const int k = (\d+);", body)] == [0, 1, 2]
    assert [int(j) for j in re.findall(r"const int j = (\d+);", body)] == [0, 1] * 3
    lines = src.text.splitlines()
    assert src.locate(lines.index("        x[k] = k;   // a comment") + 1) == "loops.glsl:5"


@pytest.mark.parametrize("loop, why", [
    ("for (int k = 0; k < M; ++k) { x[k] = 0; }", "the bound M is not an integer literal or a #define"),
    ("for (int k = 0; k < T; ++k) { x[k] = 0; }", "the bound T is not an integer literal or a #define of one"),
    ("for (int k = 0; k < 4; ++k) { if (x[k] > 0) break; }", "'break' in the loop"),
    ("for (int k = 0; k < 4; k += 2) { x[k] = 0; }", "must precede a loop"),
    ("for (int k = 0; k < 4; ++k)\n        if (x[k] > 0)\n            x[k] = 0;", "needs braces"),
])
def test_unroll_refuses_what_it_cannot_write_out(tmp_path, loop, why):
    (tmp_path / "bad.glsl").write_text("#ifdef A\n#define T 2\n#else\n#define T 4\n#endif\n"
                                       "void f(inout int x[4]) {\n    #pragma unroll\n    " + loop + "\n}\n")
    with pytest.raises(ShaderError, match=r"bad\.glsl:7: .*" + re.escape(why)):
        assemble("bad.glsl", {}, dirs=(tmp_path,))


@pytest.mark.gl
def test_unrolled_loops_compute_what_the_loops_do(gl_ctx, tmp_path):
    """The written-out loops, `continue` included, give the rolled loops' results."""
    main = "layout(local_size_x = 1) in;\nlayout(std430, binding = 0) buffer O { int o[]; };\n" \
           "void main() {\n    int x[4] = int[4](0, 0, 0, 0);\n    f(x);\n" \
           "    for (int i = 0; i < 4; ++i) o[i] = x[i];\n}\n"
    out = []
    for text in (_LOOPS, _LOOPS.replace("#pragma unroll", "")):
        (tmp_path / "loops.comp").write_text(text + main)
        buf = gl_ctx.buffer(reserve=16)
        buf.bind_to_storage_buffer(0)
        prog = gl_ctx.compute_shader(assemble("loops.comp", {}, dirs=(tmp_path,)).text)
        prog.run(1)
        out.append(np.frombuffer(buf.read(), "i4").tolist())
        prog.release()
        buf.release()
    assert out[0] == out[1] == [0, 1, 2, (0 + 10) + (20 + 30)]   # k = 1 skips its inner loop


@pytest.mark.gl
def test_compile_error_names_file_and_line(gl_ctx, tmp_path):
    (tmp_path / "broken.frag").write_text(
        '#include "camera.glsl"\nout float o;\nvoid main() {\n    o = undefined_thing;\n}\n')
    cache = ProgramCache(gl_ctx, dirs=(tmp_path,))
    with pytest.raises(ShaderError, match=r"broken\.frag:4: .*undefined_thing"):
        cache.program("fullscreen.vert", "broken.frag")


def _run_camera_check(ctx, cam: Camera, pts, pix, fp64: bool):
    cache = ProgramCache(ctx, dirs=(GLSL_DIR,))
    prog = cache.compute("camera_check.comp", {"FP64": None} if fp64 else {})
    dt = "f8" if fp64 else "f4"
    n = len(pts)
    bufs = [ctx.buffer(np.ascontiguousarray(pts, dt).tobytes()), ctx.buffer(np.ascontiguousarray(pix, dt).tobytes()),
            ctx.buffer(reserve=n * 3 * np.dtype(dt).itemsize), ctx.buffer(reserve=n * 3 * np.dtype(dt).itemsize)]
    for i, b in enumerate(bufs):
        b.bind_to_storage_buffer(i)
    for name, value in (("u_intr", cam.intrinsics), ("u_dist", cam.distortion.coeffs),
                        ("u_valid_r2", [cam.distortion.valid_radius() ** 2])):
        prog[name].write(np.asarray(value, dt).tobytes())
    prog["u_count"].value = n
    prog.run(group_x=(n + 63) // 64)
    proj = np.frombuffer(bufs[2].read(), dt).reshape(n, 3).astype(float)
    und = np.frombuffer(bufs[3].read(), dt).reshape(n, 3).astype(float)
    for b in bufs:
        b.release()
    cache.release()
    return proj, und


DISTORTIONS = {
    "barrel": Distortion(k1=-0.28, k2=0.09, p1=4e-4, p2=-3e-4),
    "pincushion": Distortion(k1=0.3),
    "full": Distortion(k1=-0.2, k2=0.05, p1=1e-3, p2=-5e-4, k3=-0.01, k4=0.02, k5=0.001, k6=0.0005,
                       s1=1e-3, s2=-2e-4, s3=5e-4, s4=1e-4),
}


@pytest.mark.gl
@pytest.mark.parametrize("name", sorted(DISTORTIONS))
@pytest.mark.parametrize("fp64,tol", [(True, 1e-9), (False, 2e-3)], ids=["fp64", "fp32"])
def test_glsl_camera_matches_opencv(gl_ctx, name, fp64, tol):
    """camera.glsl's projection vs cv2.projectPoints and its undistortion vs
    cv2.undistortPoints, over the whole image up to the corners (px)."""
    W, H = 1624, 1234
    cam = Camera(name="c", size=(W, H), fx=1800.0, fy=1790.0, cx=811.3, cy=617.9, distortion=DISTORTIONS[name])
    rng = np.random.default_rng(3)
    n = 4096
    xn = rng.uniform([-0.5, -0.37], [0.5, 0.37], (n, 2))
    pts = np.column_stack([xn, np.ones(n)]) * rng.uniform(200, 2000, (n, 1))
    pix = rng.uniform([-0.5, -0.5], [W - 0.5, H - 0.5], (n, 2))
    proj, und = _run_camera_check(gl_ctx, cam, pts, pix, fp64)
    cv_proj, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K, cam.distortion.coeffs)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-16)
    cv_und = cv2.undistortPoints(pix.reshape(-1, 1, 2), cam.K, cam.distortion.coeffs, criteria=crit).reshape(-1, 2)
    assert proj[:, 2].all() and und[:, 2].all()
    assert np.abs(proj[:, :2] - cv_proj.reshape(-1, 2)).max() < tol
    assert np.abs(und[:, :2] - cv_und).max() * cam.fx < tol


def _quads_and_targets(rng, n: int):
    """Quads of every kind, with targets inside and around them: near-parallelograms (whose
    second root lies far away), general convex quads, and folded (bow-tie) ones with two
    roots near the element."""
    base = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    kinds = []
    for jitter in (1e-9, 0.3, 1.2):   # near-parallelogram, convex, often folded
        shear = rng.uniform(-0.5, 0.5, (n, 1, 1)) * np.array([[0.0, 0.0], [0.0, 1.0], [0.0, 1.0], [0.0, 0.0]])
        p = base + shear + rng.normal(0.0, jitter, (n, 4, 2))
        kinds.append(p * rng.uniform(0.5, 20.0, (n, 1, 1)) + rng.uniform(-50, 50, (n, 1, 2)))
    p = np.concatenate(kinds)
    s, t = rng.uniform(-0.3, 1.3, (2, len(p), 1))   # (ξ, η) in [-1.6, 1.6]
    q = (p[:, 0] * (1 - s) * (1 - t) + p[:, 1] * s * (1 - t) + p[:, 2] * s * t + p[:, 3] * (1 - s) * t)
    return p, q


@pytest.mark.gl
def test_glsl_invert_closed_matches_the_oracle(gl_ctx):
    """bilinear.glsl's closed-form inverse (both roots, the far one skipped where it cannot be
    near the element) against glsim.scene.bilinear.invert_closed in float64: the same roots
    found, at the same (ξ, η) to 1e-9."""
    from glsim.scene.bilinear import invert_closed

    if not GLBackend(np.zeros((8, 8), np.float32), ctx=gl_ctx).fp64:
        pytest.skip("the driver has no GL_ARB_gpu_shader_fp64")
    p, q = _quads_and_targets(np.random.default_rng(5), 4000)
    n = len(p)
    cache = ProgramCache(gl_ctx, dirs=(GLSL_DIR,))
    prog = cache.compute("bilinear_check.comp", {"FP64": None})
    bufs = [gl_ctx.buffer(np.ascontiguousarray(p, "f8").tobytes()), gl_ctx.buffer(np.ascontiguousarray(q, "f8").tobytes()),
            gl_ctx.buffer(reserve=n * 6 * 8)]
    for i, b in enumerate(bufs):
        b.bind_to_storage_buffer(i)
    prog["u_count"].value = n
    prog.run(group_x=(n + 63) // 64)
    roots = np.frombuffer(bufs[2].read(), "f8").reshape(n, 2, 3)
    for b in bufs:
        b.release()
    cache.release()
    xi, eta, ok = invert_closed(p, q)            # (2, n) each
    gl_ok = roots[..., 2].T == 1.0
    # a root the oracle polishes to |ξ| or |η| beyond 1.5 may be dropped by the shader before
    # polishing (and the reverse): only roots near the element must agree
    near = (np.abs(xi) <= 1.4) & (np.abs(eta) <= 1.4)
    assert (gl_ok[near] == ok[near]).all()
    both = near & ok
    assert both.any(axis=0).sum() > 0.7 * n      # most targets have a root near the element …
    assert (both.sum(axis=0) == 2).sum() > 100    # … and some two: a fold near the element
    assert np.abs(roots[..., 0].T[both] - xi[both]).max() < 1e-9
    assert np.abs(roots[..., 1].T[both] - eta[both]).max() < 1e-9


@pytest.mark.gl
@pytest.mark.parametrize("stage", ["fragment", "compute"])
def test_programs_compiled_only_with_what_the_scene_asks_for(gl_ctx, stage):
    """The GL program's #defines are exactly the scene's choices: mode, interpolation,
    supersampling and precision (the pass is the entry file: single.frag or single.comp on the
    single-candidate pixels, overflow.frag on the overflowed lists; no define selects a role);
    a scene without truth maps compiles no truth outputs."""
    scene = bulge_scene(size=(203, 154), steps=1, mode="q4", interpolation="cubic", samples_per_pixel=4)
    with Renderer(scene, "gl", ctx=gl_ctx) as r:
        r.backend.stage = stage
        r.render(0, 1)
        compiled = r.backend.programs.compiled
    scene_defines = {"MODE_Q4": None, "INTERP_CUBIC": None, "SS": 2, "FP64": None}
    ext = {"fragment": "frag", "compute": "comp"}[stage]
    for entry in (f"single.{ext}", "overflow.frag"):
        assert [d for files, d in compiled if files[-1] == entry] == [scene_defines]
    assert [files for files, d in compiled if files[-1] == "overflow.frag"] == [("exact.vert", "overflow.frag")]
    assert [d for files, d in compiled if f"downsample.{ext}" in files] == [{"SS": 2}]


@pytest.mark.gl
@pytest.mark.parametrize("stage", ["fragment", "compute"])
def test_fast_mode_compiles_no_double_arithmetic(gl_ctx, stage):
    """Mode fast's programs are float32 only: its step's shape filter from its float32 nodes
    (shape.comp), its triangles (all else the fragment stage compiles) and, in the compute
    stage, their indices' shading."""
    scene = bulge_scene(size=(203, 154), steps=1, mode="fast")
    with Renderer(scene, "gl", ctx=gl_ctx) as r:
        r.backend.stage = stage
        r.render(0, 1, truth=True)
        compiled = r.backend.programs.compiled
    plain = {"INTERP_BSPLINE3", "SS", "TRUTH"}
    shape = (("shape.comp",), set())
    if stage == "fragment":
        assert [(files, set(d)) for files, d in compiled] == [shape, (("deform.vert", "fast.geom", "fast.frag"), plain)]
    else:
        assert [(files, set(d)) for files, d in compiled] == [
            shape, (("deform.vert", "fast_records.geom", "fast_ids.frag"), plain), (("fast_shade.comp",), plain)]


def test_missing_egl_gives_one_clear_error(monkeypatch):
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: None)
    with pytest.raises(GLUnavailableError, match=r"libEGL\.so was not found.*apt-get install libegl1.*backend='cpu'"):
        glctx.create_context()
    with pytest.raises(GLUnavailableError):
        GLBackend(np.zeros((4, 4), np.float32))
    # the CPU backend does not need EGL
    res = Renderer(bulge_scene(size=(101, 77), steps=1), "cpu").render(0, 1)
    assert np.isfinite(res.image).all() and res.image.max() > 0


# ---- EGL devices and multi-GPU placement ---------------------------------------------------------

def _dev(i, ext, cuda=None):
    return glctx.EglDevice(i, ext, cuda)


def test_gpu_devices_follow_cuda_order_where_the_driver_gives_it():
    """NVIDIA lists EGL devices in its own order: workers go to the GPUs in CUDA order, and a
    GPU without a CUDA ordinal (not visible to CUDA) is left out; Mesa's software device never
    counts; without CUDA ordinals every GPU in EGL order."""
    sw = "EGL_MESA_device_software EGL_EXT_device_drm_render_node"
    nv = "EGL_NV_device_cuda EGL_EXT_device_drm"
    assert glctx.gpu_devices([_dev(0, nv, 2), _dev(1, nv, 0), _dev(2, nv, None), _dev(3, sw)]) == [1, 0]
    assert glctx.gpu_devices([_dev(0, "EGL_EXT_device_drm"), _dev(1, sw), _dev(2, "EGL_EXT_device_drm")]) == [0, 2]
    assert glctx.gpu_devices([_dev(0, sw)]) == [] and glctx.gpu_devices([]) == []


def test_pool_workers_take_gpus_in_turn(monkeypatch):
    """pool_init places the k-th worker process the parent made on GPU k mod n."""
    import multiprocessing as mp
    import signal

    from glsim.workflows.library import worker
    monkeypatch.setattr(signal, "signal", lambda *args: None)   # keep this process's Ctrl-C
    got = []
    for k in range(1, 6):
        monkeypatch.setattr(mp.current_process(), "_identity", (k,))
        monkeypatch.setattr(worker, "_DEVICE", None)
        worker.pool_init((3, 1))
        got.append(worker._DEVICE)
    assert got == [3, 1, 3, 1, 3]
    monkeypatch.setattr(worker, "_DEVICE", None)
    worker.pool_init(())
    assert worker._DEVICE is None                  # no GPU: EGL's default device (llvmpipe)


def test_this_machines_devices_are_listed():
    """egl_devices() lists what `glsim info` prints; the context opens on an explicit index."""
    devices = glctx.egl_devices()
    if not devices:
        pytest.skip("EGL cannot list its devices here")
    assert [d.index for d in devices] == list(range(len(devices)))
    ctx = glctx.create_context(devices[0].index)
    try:
        assert ctx.info["GL_RENDERER"] and ctx.error == "GL_NO_ERROR"
    finally:
        ctx.release()


@pytest.mark.gl
def test_a_driver_lacking_a_limit_moderngl_asks_for_renders(gl_ctx, monkeypatch):
    """moderngl's ctx.info asks the driver for every limit it knows; Mesa's softpipe lacks one
    and answers GL_INVALID_ENUM, which the first pass's error check blamed on the ray map.
    Here ctx.info leaves that error as softpipe's does: the renderer reads the limits it needs
    (its backend's capabilities.max_size) and renders, and `glsim info` reads them too."""
    import moderngl

    answer = moderngl.Context.info.fget

    def lacking(ctx):
        ctx.enable_direct(0x1234)   # no such capability: GL_INVALID_ENUM, as softpipe leaves
        return answer(ctx)

    monkeypatch.setattr(moderngl.Context, "info", property(lacking))
    gl_ctx.info
    assert gl_ctx.error == "GL_INVALID_ENUM"    # the simulated driver does leave the error
    scene = bulge_scene(size=(96, 72), steps=1)
    with Renderer(scene, "gl", ctx=gl_ctx) as r:
        assert r.backend.capabilities.max_size == min(answer(gl_ctx)["GL_MAX_TEXTURE_SIZE"],
                                                      answer(gl_ctx)["GL_MAX_RENDERBUFFER_SIZE"])
        assert r.render(0, 1, mode="exact").image.any()
    assert glctx.info(gl_ctx)["renderer"] and gl_ctx.error == "GL_NO_ERROR"


@pytest.mark.gl
def test_renderers_on_one_context_share_their_programs(gl_ctx):
    """A second Renderer on the same context compiles nothing (programs are cached per context
    and define set) and gives the same image; its own log still lists what it used."""
    from glsim.backends.gl.programs import _shared

    scene = bulge_scene(size=(96, 72), steps=1)
    with Renderer(scene, "gl", ctx=gl_ctx) as a:
        first = a.render(0, 1, mode="exact").image
    built = len(_shared(gl_ctx))
    with Renderer(scene, "gl", ctx=gl_ctx) as b:
        again = b.render(0, 1, mode="exact").image
        assert len(_shared(gl_ctx)) == built and b.backend.programs.compiled
    assert np.array_equal(first, again)


@pytest.mark.gl
def test_uniform_values_are_written_in_each_programs_own_types(gl_ctx):
    """One Uniforms table written to two programs that declare the same names with other types
    (vec2 / ivec2 / dvec2, an array the driver keeps in part) reads back as moderngl's own
    ``.value`` setter leaves them; names a program lacks are ignored."""
    from glsim.backends.gl.uniforms import Uniforms

    def program(decl, use):
        return gl_ctx.program(
            vertex_shader="#version 450 core\n" + decl + "\nout vec4 v;\nvoid main() { v = " + use
                          + "; gl_Position = vec4(0.0); }",
            fragment_shader="#version 450 core\nin vec4 v; out vec4 c; void main() { c = v; }")

    a = program("uniform vec2 u_size; uniform float u_k[4]; uniform int u_n;",
                "vec4(u_size, u_k[1], float(u_n))")
    b = program("uniform ivec2 u_size; uniform dvec2 u_far;",
                "vec4(vec2(u_size), vec2(u_far))")
    values = {"u_size": (406, 308), "u_k": [0.1, 0.2, 0.3, 0.4], "u_n": 7, "u_far": (1.0 / 3.0, 2.5),
              "u_absent": 1.0}
    table = Uniforms(values)
    for again in (False, True):         # (twice: a second write leaves the same values)
        table.write(a)
        table.write(b)
        got = {(p, n): p[n].value for p, n in ((a, "u_size"), (a, "u_k"), (a, "u_n"), (b, "u_size"), (b, "u_far"))}
        kept = a["u_k"].array_length   # the elements the driver keeps (llvmpipe 2, up to u_k[1]; NVIDIA 4)
        a["u_size"].value, a["u_k"].value, a["u_n"].value = (406.0, 308.0), values["u_k"][:kept], 7
        b["u_size"].value, b["u_far"].value = (406, 308), (1.0 / 3.0, 2.5)
        want = {(p, n): p[n].value for p, n in got}
        assert got == want
        assert got[(b, "u_far")] == (1.0 / 3.0, 2.5)           # doubles stay doubles
    a.release()
    b.release()


_SAMPLER_DECL = r"^\s*(layout\(binding = SAMPLER_(\w+)\) )?uniform (?:u?sampler\w+|RAY_SAMPLER) (u_\w+);"


def test_every_packaged_sampler_has_its_fixed_unit():
    """Each sampler the packaged shaders declare is bound by layout to the unit of its name in
    glsim.backends.gl.bindings.SAMPLERS (so no frame sets it); the units are distinct and below
    16, GL 4.5's least number of texture units per shader stage."""
    import re
    from importlib import resources

    from glsim.backends.gl.bindings import SAMPLERS, defines

    found = {}
    for f in resources.files("glsim.shaders").iterdir():
        for m in re.finditer(_SAMPLER_DECL, f.read_text(), re.M):
            assert m.group(1) and m.group(2) == m.group(3)[2:].upper(), f"{f.name}: {m.group(0).strip()}"
            found[m.group(3)] = f.name
    assert set(found) == set(SAMPLERS)
    assert len(set(SAMPLERS.values())) == len(SAMPLERS) and max(SAMPLERS.values()) < 16
    assert all(f"#define SAMPLER_{n[2:].upper()} {u}" in defines() for n, u in SAMPLERS.items())


def test_no_packaged_shader_reads_a_runtime_arrays_length():
    """No packaged shader takes .length() of a runtime-sized array: zink (Mesa 22.3, GL on
    lavapipe) gave the float32 exact resolve.comp a wrong one, and its samples read other list
    entries (glsim check's pixel-stage row: 2.6e5 values off). The compute stage's lists end
    where their W × H count image says (pixellists.glsl's LIST_END)."""
    from importlib import resources

    used = [(f.name, n) for f in resources.files("glsim.shaders").iterdir() if f.name.endswith((".glsl", ".frag",
                                                                                             ".comp", ".vert", ".geom"))
            for n, line in enumerate(f.read_text().splitlines(), 1)
            if ".length()" in line.split("//")[0]]
    assert used == []


@pytest.mark.gl
@pytest.mark.parametrize("mode", ["fast", "exact"])
def test_linked_samplers_read_their_table_units(gl_ctx, mode):
    """After a render at 4 spp, quantised on the GPU, every sampler of every program the context
    built holds its table unit as the driver linked it (GL 4.2 layout bindings; the effects'
    passes are checked against the oracle by their own tests, which a wrong unit would fail)."""
    from glsim.backends.gl.bindings import SAMPLERS
    from glsim.backends.gl.programs import _shared

    scene = bulge_scene(size=(96, 72), steps=1)
    with Renderer(scene, "gl", ctx=gl_ctx) as r:
        r.render(0, 1, mode=mode, samples_per_pixel=4, quantize=True)
    seen = 0
    for prog in _shared(gl_ctx).values():
        for name, unit in SAMPLERS.items():
            u = prog.get(name, None)
            if u is not None:
                assert u.value == unit, (name, u.value)
                seen += 1
    assert seen >= (3 if mode == "fast" else 6)   # u_ref, u_samples, u_src (+ rays, lists)


@pytest.mark.gl
def test_a_table_sampler_without_its_layout_is_refused(gl_ctx, tmp_path):
    """A shader that declares a table sampler without its binding would read unit 0 while the
    frame binds its texture elsewhere: building it is refused, naming the declaration to write."""
    (tmp_path / "bad.frag").write_text("uniform sampler2D u_src;\nout float out_grey;\n"
                                       "void main() { out_grey = texelFetch(u_src, ivec2(0), 0).r; }\n")
    cache = ProgramCache(gl_ctx, dirs=(tmp_path,))
    with pytest.raises(ShaderError, match=r"sampler u_src reads texture unit 0, not its unit 5; declare it as "
                                          r"layout\(binding = SAMPLER_SRC\)"):
        cache.program("fullscreen.vert", "bad.frag")
    cache.release()


def _packaged():
    from importlib import resources

    return {f.name: f.read_text() for f in resources.files("glsim.shaders").iterdir()
            if f.name.endswith((".glsl", ".frag", ".comp", ".vert", ".geom"))}


def test_every_packaged_entry_file_is_one_entry_point():
    """Each packaged .frag, .comp, .vert and .geom has one main and includes only the .glsl
    library (no entry file includes another); no .glsl has a main; each fragment entry has its
    program in programs.PROGRAMS; and no shader file is over 250 lines."""
    from glsim.backends.gl.programs import PROGRAMS

    files = _packaged()
    for name, text in files.items():
        mains = len(re.findall(r"^\s*void\s+main\s*\(", text, re.M))
        assert mains == (0 if name.endswith(".glsl") else 1), (name, mains)
        included = re.findall(r'^\s*#include\s+"([^"]+)"', text, re.M)
        assert all(f.endswith(".glsl") and f in files for f in included), (name, included)
        assert len(text.splitlines()) <= 250, (name, len(text.splitlines()))
    assert {n for n in files if n.endswith(".frag")} == set(PROGRAMS)
    assert all(set(stages) <= set(files) for stages in PROGRAMS.values())


def test_no_define_selects_a_shader_role():
    """The pass is the entry file: none of the defines that once chose a role inside a shared
    file (the pixel stage, the pass 2 variant, the list reader or writer) is left."""
    gone = ("COMPUTE_PIXELS", "EARLY_TESTS", "FALLBACK", "RESOLVE", "PIXEL_LOOP", "FAST_VISIBILITY",
            "CANDIDATE_TEXTURES", "LIST_WRITER", "GREY_PASS", "MODE_FAST")
    used = {(name, d) for name, text in _packaged().items() for d in gone if re.search(rf"\b{d}\b", text)}
    assert not used, sorted(used)
