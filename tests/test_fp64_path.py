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
    ("blur.frag", "3.194528"): "a float constant of the float32 blur",
    ("noise.glsl", "6.283185307179586"): "2π in the float32 noise",
    ("shade.glsl", "0.2"): "a float32 series coefficient of the Phong shading",
    ("raymap.glsl", "1e30"): "NO_RAY test of float32 builds (any value ≥ 1e30 is NO_RAY)",
    ("rays.frag", "1e30"): "NO_RAY: written as float32, read with ≥ 1e30",
    ("view.glsl", "1e30"): "FAR_AWAY: a sentinel compared with ≥, never used in arithmetic",
}


def test_inexact_literals_carry_a_suffix():
    """A literal float32 cannot hold exactly (1e-12, 0.1) is float32 in GLSL unless suffixed
    lf: in a double expression it would bring float32 rounding (2^-24 relative) into it."""
    found = set()
    for path in sorted(SHADERS.iterdir()):
        if path.suffix == ".py":
            continue
        for line in path.read_text().splitlines():
            for m in _LITERAL.finditer(line.split("//")[0]):
                text, suffix = m.groups()
                if suffix is None and any(c in text for c in ".eE") and float(np.float32(text)) != float(text):
                    found.add((path.name, text))
    assert found <= set(FLOAT32_LITERALS), sorted(found - set(FLOAT32_LITERALS))


# float→double conversions allowed in float64 programs, by the converted value's name: each
# holds values float32 represents exactly
EXACT_FLOAT_SOURCES = {
    "gl_FragCoord": "half-integer pixel coordinates (< 2^23)",
    "u_ref_size": "the reference image's width and height in px (integers)",
    "u_size": "the image's width and height in px (integers)",
}


def _conversions(stage: str, text: str) -> set[str]:
    """The names under each 'Convert float to double' node of glslang's intermediate tree."""
    tree = subprocess.run(["glslangValidator", "--stdin", "-S", stage, "-i"], input=text, capture_output=True,
                          text=True, check=True).stdout.splitlines()
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


@pytest.mark.gl
@pytest.mark.skipif(shutil.which("glslangValidator") is None,
                    reason="glslangValidator not installed (make test installs Debian's glslang-tools as root)")
def test_float64_programs_convert_from_float_only_exact_values(gl_ctx):
    """Every float64 program built for exact and q4 renders (1 and 4 spp, truth, Newton
    sub-samples) converts float to double only for values float32 holds exactly
    (EXACT_FLOAT_SOURCES): no float step in the double path."""
    scene = bulge_scene(size=(96, 72), steps=1)
    built = []
    with Renderer(scene, "gl", ctx=gl_ctx) as r:
        for mode in ("exact", "q4"):
            for spp in (1, 4):
                r.render(1, 1, truth=True, mode=mode, samples_per_pixel=spp)
        r.render(1, 1, mode="exact", samples_per_pixel=4, subsamples="newton")
        built += r.backend.programs.compiled
    fp64 = [(files, d) for files, d in built if "FP64" in d]
    assert len(fp64) >= 6
    stages = {"vert": "vert", "frag": "frag", "comp": "comp"}
    bad = {}
    for files, defines in fp64:
        for f in files:
            names = _conversions(stages[f.rsplit(".", 1)[1]], assemble(f, defines).text)
            for n in names - set(EXACT_FLOAT_SOURCES):
                bad.setdefault(n, set()).add(f)
    assert not bad, bad


@pytest.mark.gl
def test_double_path_primitives_are_bit_for_bit_numpys(gl_ctx):
    """split_double, pixel_to_normalized, pinhole_corners, the ray edge functions, distort and
    normalized_to_pixel against numpy on 4096 random inputs (glsim.evaluation.check.fp64_probe, also `glsim check`'s first
    check): equal bit for bit — the driver honours `precise` and computes doubles in double."""
    from glsim.backends.gl.backend import GLBackend
    from glsim.evaluation.check import fp64_probe

    if not GLBackend(np.zeros((8, 8), np.float32), ctx=gl_ctx).fp64:
        pytest.skip("the driver has no GL_ARB_gpu_shader_fp64")
    assert fp64_probe(gl_ctx) == {"split_double": 0, "pixel_to_normalized": 0, "pinhole_corners": 0,
                                  "edge_functions": 0, "distort": 0, "normalized_to_pixel": 0}
