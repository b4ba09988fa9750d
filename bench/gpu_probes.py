"""Driver probes a GPU session runs first (bench/gpu-session.sh, step "probe"; seconds):

- arrays: for each way of writing and reading a small local array of doubles, and for a few `lf`
  literals, the number of 256 results that differ from numpy in any bit ("compile error" where
  the driver refuses the shader). README "glsim check" has the H100's answers.
- passes: the same `precise` float64 per-pixel work (a recurrence of ITER steps, 0: writing
  only) drawn into a 1624 × 1234 R32F image as a fragment pass and as a compute pass
  (imageStore): per pass the GPU time (timer query) and the wall time to glFinish, medians of
  REPS (llvmpipe's timer queries do not cover its deferred work: read its wall times). A
  data-centre GPU is said to shade fragments on few of its SMs through few ROPs (8 on the H100).

    python bench/gpu_probes.py OUT.json
"""
import json
import statistics
import sys
import time

import numpy as np

from glsim.backends.gl.context import create_context

N = 256
WAYS = {   # name: (GLSL setting r from d's inputs inp[b…b+8], what r must be: column, -m for column i % m, or "sum")
    "loop writes, constant read": ("double d[5]; for (int j = 0; j < 5; ++j) d[j] = inp[b + j]; r = d[2];", 2),
    "loop writes, variable read": ("double d[2]; for (int j = 0; j < 2; ++j) d[j] = inp[b + j]; r = d[i % 2];", -2),
    "constant writes, variable read": ("double d[9]; d[0]=inp[b]; d[1]=inp[b+1]; d[2]=inp[b+2]; d[3]=inp[b+3]; "
                                       "d[4]=inp[b+4]; d[5]=inp[b+5]; d[6]=inp[b+6]; d[7]=inp[b+7]; d[8]=inp[b+8]; "
                                       "r = d[i % 9];", -9),
    "summed by a loop": ("double d[9]; for (int j = 0; j < 9; ++j) d[j] = inp[b + j]; precise double s = 0.0lf; "
                         "for (int j = 0; j < 9; ++j) s += d[j]; r = s;", "sum"),
    "dvec2 array, variable read": ("dvec2 d[5]; for (int j = 0; j < 5; ++j) d[j] = dvec2(inp[b + j], 0.0lf); "
                                   "r = d[i % 5].x;", -5),
    "dvec2 component, variable write": ("dvec2 d; for (int j = 0; j < 2; ++j) d[j] = inp[b + j]; r = d[1];", 1),
    "uniform array, variable read": ("r = u_d[i % 5];", "uniform"),
    "out array of a function": ("double d[2]; fill2(b, d); r = d[1];", 1),
    "literal 0.1lf": ("r = 0.1lf;", 0.1),
    "literal 1e-14lf": ("r = 1e-14lf;", 1e-14),
    "literal 1.0lf / 10.0lf": ("r = 1.0lf / 10.0lf;", 0.1),
}
HEAD = """#version 450 core
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer In { double inp[]; };
layout(std430, binding = 1) writeonly buffer Out { double o[]; };
uniform double u_d[5];
void fill2(int b, out double d[2]) { for (int j = 0; j < 2; ++j) d[j] = inp[b + j]; }
void main() { int i = int(gl_GlobalInvocationID.x); int b = 9 * i; double r; """


SIZE = (1624, 1234)
REPS = 15
BODY = """    precise double x = double(p.x) * 0.0009765625lf + double(p.y);
    for (int i = 0; i < ITER; ++i) x = x * x * 0.5lf + 0.25lf;"""
FRAG = """#version 450 core
#define ITER {iter}
out float o;
void main() {{
    ivec2 p = ivec2(gl_FragCoord.xy);
{body}
    o = float(x);
}}"""
VERT = """#version 450 core
void main() { gl_Position = vec4(vec2((gl_VertexID << 1) & 2, gl_VertexID & 2) * 2.0 - 1.0, 0.0, 1.0); }"""
COMP = """#version 450 core
#define ITER {iter}
layout(local_size_x = 16, local_size_y = 8) in;
layout(r32f, binding = 0) writeonly uniform image2D img;
void main() {{
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(p, imageSize(img)))) return;
{body}
    imageStore(img, p, vec4(float(x)));
}}"""


def _median_ms(ctx, run) -> tuple[float, float]:
    """(GPU ms, wall ms to glFinish) of ``run``, medians after two warm-up runs."""
    gpu, wall = [], []
    for _ in range(REPS + 2):
        q = ctx.query(time=True)
        ctx.finish()
        t = time.perf_counter()
        with q:
            run()
        ctx.finish()
        wall.append((time.perf_counter() - t) * 1e3)
        gpu.append(q.elapsed / 1e6)
    return statistics.median(gpu[2:]), statistics.median(wall[2:])


def arrays(ctx) -> dict:
    """The arrays probe: {way: differing results or "compile error: …"}."""
    x = np.random.default_rng(3).uniform(100, 1000, (N, 9)) / 3
    u = np.arange(1, 6) / 3.0
    i = np.arange(N)
    src_in, src_out = ctx.buffer(x.tobytes()), ctx.buffer(reserve=N * 8)
    src_in.bind_to_storage_buffer(0)
    src_out.bind_to_storage_buffer(1)
    res = {}
    for name, (code, want) in WAYS.items():
        try:
            prog = ctx.compute_shader(HEAD + code + " o[i] = r; }")
        except Exception as exc:   # the driver's refusal is the result
            res[name] = "compile error: " + str(exc).strip().splitlines()[-1][:100]
            continue
        if "u_d" in prog:
            prog["u_d"].write(u.tobytes())
        prog.run(N // 64)
        got = np.frombuffer(src_out.read(), "f8")
        prog.release()
        if want == "sum":
            ref = sum(x[:, c] for c in range(9))
        elif want == "uniform":
            ref = u[i % 5]
        elif isinstance(want, float):
            ref = np.full(N, want)
        else:
            ref = x[i, i % -want] if want < 0 else x[:, want]
        res[name] = int((got.view(np.uint64) != ref.view(np.uint64)).sum())
    src_in.release()
    src_out.release()
    return res


def passes(ctx) -> dict:
    """The passes probe: {"iter K": GPU and wall ms of each way, whether both wrote the same bytes}."""
    tex = ctx.texture(SIZE, 1, dtype="f4")
    fbo = ctx.framebuffer(color_attachments=[tex])
    vao = None
    res = {"size": list(SIZE), "reps": REPS}
    for it in (0, 16, 64):
        prog = ctx.program(vertex_shader=VERT, fragment_shader=FRAG.format(iter=it, body=BODY))
        vao = ctx.vertex_array(prog, [])
        fbo.use()

        def frag():
            vao.render(mode=ctx.TRIANGLES, vertices=3)
        frag_ms, frag_wall = _median_ms(ctx, frag)
        a = tex.read()
        comp = ctx.compute_shader(COMP.format(iter=it, body=BODY))
        tex.bind_to_image(0, read=False, write=True)

        def run():
            comp.run((SIZE[0] + 15) // 16, (SIZE[1] + 7) // 8)
        comp_ms, comp_wall = _median_ms(ctx, run)
        ctx.memory_barrier()
        same = tex.read() == a
        res[f"iter {it}"] = {"fragment_gpu_ms": frag_ms, "compute_gpu_ms": comp_ms, "fragment_wall_ms": frag_wall,
                             "compute_wall_ms": comp_wall, "same_bytes": same}
        for o in (vao, prog, comp):
            o.release()
    fbo.release()
    tex.release()
    return res


def main(out: str) -> None:
    ctx = create_context()
    res = {"renderer": ctx.info["GL_RENDERER"], "version": ctx.info["GL_VERSION"], "arrays": arrays(ctx),
           "passes": passes(ctx)}
    ctx.release()
    text = json.dumps(res, indent=1)
    print(text)
    with open(out, "w") as f:
        f.write(text + "\n")


if __name__ == "__main__":
    main(sys.argv[1])
