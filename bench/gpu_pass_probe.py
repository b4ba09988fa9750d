"""Fragment pass or compute pass: the same per-pixel work timed both ways (run by
bench/gpu-session.sh, step "probe"). A data-centre GPU may run fragment shaders on a few of its
SMs and write them through few ROPs (the H100 is said to have 8); a compute shader uses every SM
and writes with imageStore. Each way draws a 1624 × 1234 R32F image: a float64 recurrence of
ITER steps per pixel (0: writing only); per pass the GPU time (timer query) and the wall time to
glFinish, medians of REPS (llvmpipe's timer queries do not cover its deferred work: read its wall
times).

    python bench/gpu_pass_probe.py OUT.json
"""
import json
import statistics
import sys
import time

from glsim.backends.gl.context import create_context

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


def main(out: str) -> None:
    ctx = create_context()
    tex = ctx.texture(SIZE, 1, dtype="f4")
    fbo = ctx.framebuffer(color_attachments=[tex])
    vao = None
    res = {"renderer": ctx.info["GL_RENDERER"], "size": list(SIZE), "reps": REPS}
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
    ctx.release()
    text = json.dumps(res, indent=1)
    print(text)
    with open(out, "w") as f:
        f.write(text + "\n")


if __name__ == "__main__":
    main(sys.argv[1])
