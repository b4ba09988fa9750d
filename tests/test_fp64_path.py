"""The float64 path of the shaders, guarded on whatever driver runs the tests (issue 25).

GLSL only asks double operations to be as precise as float (GLSL 4.50 §4.7.1); NVIDIA contracts
``a*b - c`` into an fma unless the result is ``precise``, and a compiler may fold a
double→float→double round trip to the identity. These tests hold the shaders to the rules of
design-notes "GPU facts" without a GPU:
- every floating literal that float32 cannot represent carries a suffix (``lf``), unless listed
  below as float32 code;
- in every float64 program the GL backend builds, each float→double conversion (glslang's
  intermediate tree) is one of an audited list of values that float32 holds exactly;
- the double-path primitives give their numpy twins' results bit for bit (probe).
"""
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from glsim.backends.gl.programs import assemble
from glsim.render import Renderer
from glsim.scene import bulge_scene

SHADERS = Path(__file__).parents[1] / "shaders"

_LITERAL = re.compile(r"(?<![\w.])((?:\d+\.\d*|\.\d+|\d+)(?:[eE][+-]?\d+)?)(lf|LF|f|F|u|U)?(?![\w.])")
# Inexact literals without a suffix that are float32 on purpose: (file, literal) → why
FLOAT32_LITERALS = {
    ("bilinear.glsl", "1e-6"): "NEWTON_TOL of float32 builds (#else of FP64)",
    ("bilinear.glsl", "1e-3"): "NEAR_TOL of float32 builds",
    ("camera.glsl", "2e-7"): "UNDISTORT_TOL of float32 builds",
    ("quadratic.glsl", "1e-6"): "Q_TOL of float32 builds",
    ("quadratic.glsl", "1e-5"): "Q_RESIDUAL of float32 builds",
    ("subsamples.frag", "1e-4"): "SUBSAMPLE_TOL of float32 builds",
    ("blur_expansion.glsl", "3.194528"): "a float constant of the float32 blur",
    ("noise.glsl", "6.283185307179586"): "2π in the float32 noise",
    ("shade.glsl", "0.2"): "a float32 series coefficient of the Phong shading",
    ("raymap.glsl", "1e30"): "NO_RAY test of float32 builds (any value ≥ 1e30 is NO_RAY)",
    ("rays.frag", "1e30"): "NO_RAY: written as float32, read with ≥ 1e30",
    ("view.glsl", "1e30"): "FAR_AWAY: a sentinel compared with ≥, never used in arithmetic",
}


def _inexact_literals():
    """(file, literal, suffix or None) of each floating literal in the shaders (comments left
    out) whose value float32 cannot hold."""
    for path in sorted(SHADERS.iterdir()):
        if path.suffix == ".py":
            continue
        for line in path.read_text().splitlines():
            for m in _LITERAL.finditer(line.split("//")[0]):
                text, suffix = m.groups()
                if any(c in text for c in ".eE") and float(np.float32(text)) != float(text):
                    yield path.name, text, suffix


def test_inexact_literals_carry_a_suffix():
    """A literal float32 cannot hold exactly (1e-12, 0.1) is float32 in GLSL unless suffixed
    lf: in a double expression it would bring float32 rounding (2^-24 relative) into it."""
    found = {(f, text) for f, text, suffix in _inexact_literals() if suffix is None}
    assert found <= set(FLOAT32_LITERALS), sorted(found - set(FLOAT32_LITERALS))


# Suffixed double literals whose value is not exact in float32: NVIDIA's compiler reads them up to
# an ulp off (0.1lf as 0.09999999999999999; H100, 2026-11-27), so each is a threshold where an ulp
# decides nothing the oracle would decide otherwise. (file, literal) → why
DOUBLE_LITERALS = {
    ("bilinear.glsl", "1e-12"): "NEWTON_TOL and the closed form's linear test: step and coefficient sizes",
    ("bilinear.glsl", "1e-6"): "NEAR_TOL: 1 ± NEAR_TOL rounds alike for values an ulp apart",
    ("camera.glsl", "1e-14"): "UNDISTORT_TOL: undistort's residual threshold",
    ("quadratic.glsl", "1e-13"): "Q_TOL: Newton's step threshold",
    ("quadratic.glsl", "1e-9"): "Q_RESIDUAL, Q_INSIDE: a residual and 1 ± Q_INSIDE",
    ("raymap.glsl", "1e30"): "NO_RAY: compared with <",
    ("subsamples.frag", "1e-7"): "SUBSAMPLE_TOL: Newton's step threshold",
    ("view.glsl", "1e-6"): "the cover's round-off margin (a conservative bound)",
}


def test_double_literals_are_thresholds_only():
    """Every `lf` literal float32 cannot hold is a listed threshold (DOUBLE_LITERALS): values
    that enter the results exactly are integers, dyadic, or bits (plan.aperture_literal)."""
    found = {(f, text) for f, text, suffix in _inexact_literals() if suffix in ("lf", "LF")}
    assert found == set(DOUBLE_LITERALS), sorted(found ^ set(DOUBLE_LITERALS))


# float→double conversions allowed in float64 programs, by the converted value's name: each
# holds values float32 represents exactly
EXACT_FLOAT_SOURCES = {
    "gl_FragCoord": "half-integer pixel coordinates (< 2^23)",
    "at": "pass 2's sample texel (owners.glsl's locate_sample: vec2(at) + 0.5, gl_FragCoord in a fragment pass)",
    "u_ref_size": "the reference image's width and height in px (integers)",
    "u_size": "the image's width and height in px (integers)",
    "hl": "fp64_probe.comp writes split_double's float32 halves out as doubles",
    "f32": "shape.comp compares an area bound's float32 rounding with the double it rounds",
}


def _conversions(tree: list[str]) -> set[str]:
    """The names under each 'Convert float to double' node of glslang's intermediate tree."""
    out = [re.sub(r"^\d+:\d+", "", line) for line in tree]   # (the source line, then the depth)
    names = set()
    for k, line in enumerate(out):
        if "Convert float to double" in line:
            depth = len(line) - len(line.lstrip())
            for below in out[k + 1:]:
                if len(below) - len(below.lstrip()) <= depth:
                    names.add("<expression without a name>")
                    break
                m = re.search(r"'(\w+)'", below)
                if m:
                    names.add(m.group(1))
                    break
    return names


_GLSLANG = pytest.mark.skipif(shutil.which("glslangValidator") is None,
                              reason="glslangValidator not installed (make test installs Debian's glslang-tools as root)")
_STAGES = {"vert": "vert", "frag": "frag", "comp": "comp", "geom": "geom"}


@pytest.fixture(scope="module")
def fp64_programs(gl_ctx):
    """(files, defines) of every float64 program the GL backend builds for exact and q4 renders
    (1 and 4 spp, truth, Newton sub-samples, both pixel stages, pinhole cameras, a fill factor
    below 1, float32 samples over float64 records, lit quadratic Q8 and T6 patches in both
    stages), and the probe of glsim check."""
    from _plates import plate_scene
    from glsim.bench import quadratic

    built = [(("fp64_probe.comp",), {"FP64": None})]
    with Renderer(bulge_scene(size=(96, 72), steps=1), "gl", ctx=gl_ctx) as r:
        for r.backend.stage in ("fragment", "compute"):
            for mode in ("exact", "q4"):
                for spp in (1, 4):
                    r.render(1, 1, truth=True, mode=mode, samples_per_pixel=spp)
            r.render(1, 1, mode="exact", samples_per_pixel=4, subsamples="newton")
        built += r.backend.programs.compiled
    pinhole = plate_scene(size=(64, 48), mode="exact")   # pinhole cameras: REF_PINHOLE, PIXEL_TIES
    with Renderer(pinhole, "gl", ctx=gl_ctx) as r, \
            Renderer(pinhole.replace(sensor={"fill_factor": 0.3}), "gl", ctx=gl_ctx) as f:
        for mode in ("exact", "q4"):
            r.render(0, 0, truth=True, mode=mode, samples_per_pixel=4)
        r.render(0, 0, truth=True, mode="exact", precision="fp32")   # RECORD_LOCAL records
        f.render(0, 0, truth=True, samples_per_pixel=4)
        built += r.backend.programs.compiled + f.backend.programs.compiled
    lit = {"lights": [{"position": [30, -20, 0]}], "ambient": 0.2}
    for kind in ("quad8", "triangle6"):
        with Renderer(quadratic.paraboloid_scene((64, 48)).replace(lighting=lit), "gl", ctx=gl_ctx,
                      mesh=quadratic.mesh(kind, 2, 2)) as r:
            for r.backend.stage in ("fragment", "compute"):
                for mode in ("exact", "q4"):
                    r.render(0, 0, truth=True, mode=mode)
            built += r.backend.programs.compiled
    fp64 = {(files, tuple(sorted(d.items(), key=str))): (files, d) for files, d in built if "FP64" in d}
    assert len(fp64) >= 8
    return list(fp64.values())


def _tree(f: str, defines: dict) -> list[str]:
    return subprocess.run(["glslangValidator", "--stdin", "-S", _STAGES[f.rsplit(".", 1)[1]], "-i"],
                          input=assemble(f, defines).text, capture_output=True, text=True, check=True).stdout.splitlines()


@pytest.mark.slow   # glslangValidator on every float64 program
@pytest.mark.both_stages
@pytest.mark.gl
@_GLSLANG
def test_float64_programs_convert_from_float_only_exact_values(fp64_programs):
    """Every float64 program built for exact and q4 renders converts float to double only for
    values float32 holds exactly (EXACT_FLOAT_SOURCES): no float step in the double path."""
    bad = {}
    for files, defines in fp64_programs:
        for f in files:
            for n in _conversions(_tree(f, defines)) - set(EXACT_FLOAT_SOURCES):
                bad.setdefault(n, set()).add(f)
    assert not bad, bad


# a variable of the function (not a uniform, buffer or constant) holding doubles, in glslang's tree
_LOCAL_DOUBLES = re.compile(r"'(\w+)' \( (?:temp|in|out|inout) [^)]*double")


@pytest.mark.slow   # glslangValidator on every float64 program
@pytest.mark.both_stages
@pytest.mark.gl
@_GLSLANG
def test_float64_programs_index_their_double_arrays_by_constants_only(fp64_programs):
    """No float64 program indexes a local array (or vector) of doubles by a variable: NVIDIA
    keeps such an array in memory that holds doubles as float32 (README, "glsim check",
    H100 2026-11-27: every read rounded to float32; constant indices keep every bit). Loops over
    corners, roots and nodes are written out by the loader (``#pragma unroll``,
    glsim.backends.gl.programs._unroll); glslang's tree marks each remaining variable index
    "indirect index", whose indexed operand is checked here."""
    bad = set()
    for files, defines in fp64_programs:
        for f in files:
            tree, src = _tree(f, defines), assemble(f, defines)
            for k, line in enumerate(tree[:-1]):
                if line.rstrip().endswith(")") and "indirect index" in line:
                    m = _LOCAL_DOUBLES.search(tree[k + 1])
                    if m:
                        bad.add((src.locate(int(line.split(":")[1].split()[0])), m.group(1)))
    assert not bad, sorted(bad)


@pytest.mark.gl
def test_double_path_primitives_are_bit_for_bit_numpys(gl_ctx):
    """split_double, pixel_to_normalized, pinhole_corners, the ray edge functions, distort and
    normalized_to_pixel against numpy on 4096 random inputs (glsim.check.runner.fp64_probe, also `glsim check`'s first
    check): equal bit for bit — the driver honours `precise` and computes doubles in double."""
    from glsim.backends.gl.backend import GLBackend
    from glsim.check.runner import fp64_probe

    if not GLBackend(np.zeros((8, 8), np.float32), ctx=gl_ctx).fp64:
        pytest.skip("the driver has no GL_ARB_gpu_shader_fp64")
    assert fp64_probe(gl_ctx) == {"split_double": 0, "pixel_to_normalized": 0, "pinhole_corners": 0,
                                  "edge_functions": 0, "distort": 0, "normalized_to_pixel": 0}


def _probes():
    """bench/gpu_probes.py as a module (the GPU session's probes are a script, not package code)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("gpu_probes", Path(__file__).parents[1] / "bench" / "gpu_probes.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.gl
def test_array_probe_reports_every_way(gl_ctx):
    """bench/gpu_probes.py's arrays probe (a GPU session's first step) reports each way; the ways
    every driver measured so far keeps bit for bit (llvmpipe; the H100: constant indices,
    uniform arrays, an exact division) are 0 here too."""
    probe = _probes()
    got = probe.arrays(gl_ctx)
    assert set(got) == set(probe.WAYS)
    assert all(isinstance(v, int) or v.startswith("compile error") for v in got.values())
    assert got["loop writes, constant read"] == got["uniform array, variable read"] == got["literal 1.0lf / 10.0lf"] == 0


@pytest.mark.gl
def test_pass_probe_draws_the_same_image_both_ways(gl_ctx, tmp_path):
    """bench/gpu_probes.py's passes probe times a fragment and a compute pass doing the same
    `precise` float64 work: both write the same bytes (a like-for-like comparison), each time
    reported; the script writes both probes to its JSON file."""
    probe = _probes()
    probe.SIZE, probe.REPS = (96, 72), 2
    probe.main(str(tmp_path / "p.json"))
    got = json.loads((tmp_path / "p.json").read_text())
    assert set(got["arrays"]) == set(probe.WAYS)
    for it in (0, 16, 64):
        row = got["passes"][f"iter {it}"]
        assert row["same_bytes"] is True
        assert all(row[k] >= 0 for k in ("fragment_gpu_ms", "compute_gpu_ms", "fragment_wall_ms", "compute_wall_ms"))
