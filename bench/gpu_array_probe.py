"""What a driver does with local double arrays and double literals (run by bench/gpu-session.sh,
step "probe"; README "glsim check" has the H100's answers): for each way of writing and reading
a small local array of doubles, and for a few `lf` literals, the number of 256 results that
differ from numpy in any bit; "compile error" where the driver refuses the shader.

    python bench/gpu_array_probe.py OUT.json
"""
import json
import sys

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


def main(out: str) -> None:
    ctx = create_context()
    x = np.random.default_rng(3).uniform(100, 1000, (N, 9)) / 3
    u = np.arange(1, 6) / 3.0
    i = np.arange(N)
    src_in, src_out = ctx.buffer(x.tobytes()), ctx.buffer(reserve=N * 8)
    src_in.bind_to_storage_buffer(0)
    src_out.bind_to_storage_buffer(1)
    res = {"renderer": ctx.info["GL_RENDERER"], "version": ctx.info["GL_VERSION"]}
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
    ctx.release()
    text = json.dumps(res, indent=1)
    print(text)
    with open(out, "w") as f:
        f.write(text + "\n")


if __name__ == "__main__":
    main(sys.argv[1])
