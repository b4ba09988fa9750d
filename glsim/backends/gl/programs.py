"""GLSL loader: resolves #include, prepends #version/#defines, caches programs, and turns
driver logs into errors that name the shader file and line."""
from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from glsim.backends.gl import bindings
from glsim.errors import ShaderError

VERSION = "#version 450 core"
PRECISION = """#ifdef FP64
#define real double
#define real2 dvec2
#define real3 dvec3
#define real4 dvec4
#define real2x2 dmat2
#define real3x3 dmat3
#else
#define real float
#define real2 vec2
#define real3 vec3
#define real4 vec4
#define real2x2 mat2
#define real3x3 mat3
#endif"""
_INCLUDE = re.compile(r'^\s*#include\s+"([^"]+)"\s*$')
_UNROLL = re.compile(r"^\s*#pragma\s+unroll\s*$")
_FOR = re.compile(r"^(\s*)for\s*\(\s*int\s+(\w+)\s*=\s*(\w+)\s*;\s*\2\s*(<=?)\s*(\w+)\s*;\s*(?:\+\+\2|\2\+\+)\s*\)\s*(.*)$")
_INT_DEFINE = re.compile(r"^\s*#define\s+(\w+)\s+(-?\d+)\s*(?://.*)?$")
# Each fragment entry file's program: the shader files before it (vertex, then geometry). Every
# packaged .frag and .comp is one entry point (one main) that includes the .glsl library it
# needs; a .comp is a program of its own.
PROGRAMS = {
    "fast.frag": ("deform.vert", "fast.geom"),
    "fast_ids.frag": ("deform.vert", "fast_records.geom"),
    "single.frag": ("lists.vert",),
    "resolve.frag": ("lists.vert",),
    "subsamples.frag": ("lists.vert",),
    "overflow.frag": ("exact.vert",),
    "classify.frag": ("lists.vert",),
    "candidates.frag": ("exact.vert",),
    **{f"{name}.frag": ("fullscreen.vert",) for name in ("rays", "downsample", "blur", "vignette", "psf", "fpn",
                                                         "noise", "quantize")},
}
# Mesa: "0:12(5): error: ..."; NVIDIA: "0(12) : error C1008: ..."
_LOG_LINE = re.compile(r"^\s*\d+[:(](\d+)\)?(?:\(\d+\))?\s*:\s*(.*)$")


def read_shader(name: str, dirs: tuple = ()) -> str:
    """Text of a shader file: first found in ``dirs``, then in the packaged shaders."""
    for d in dirs:
        path = Path(d) / name
        if path.is_file():
            return path.read_text()
    try:
        return resources.files("glsim.shaders").joinpath(name).read_text()
    except FileNotFoundError:
        raise ShaderError(f"shader file {name!r} not found in {[str(d) for d in dirs]} or glsim.shaders") from None


@dataclass(frozen=True)
class Source:
    """An assembled GLSL source and, for each of its lines, the (file, line) it came from."""
    text: str
    origin: tuple[tuple[str, int], ...]

    def locate(self, line: int) -> str:
        if 1 <= line <= len(self.origin):
            f, n = self.origin[line - 1]
            return f"{f}:{n}"
        return f"<assembled>:{line}"


def assemble(name: str, defines: dict | None = None, dirs: tuple = ()) -> Source:
    """#version, one #define per item (value None → bare define), precision macros, the binding
    table (glsim.backends.gl.bindings), then the
    file with its #include "x.glsl" lines replaced (each file included once)."""
    lines: list[str] = [VERSION]
    origin: list[tuple[str, int]] = [("<version>", 1)]
    for key, value in sorted((defines or {}).items()):
        lines.append(f"#define {key}" + ("" if value is None else f" {value}"))
        origin.append(("<defines>", len(origin)))
    for i, text in enumerate(PRECISION.splitlines(), 1):
        lines.append(text)
        origin.append(("<precision>", i))
    for i, text in enumerate(bindings.defines().splitlines(), 1):
        lines.append(text)
        origin.append(("<bindings>", i))
    seen: set[str] = set()

    def add(fname: str) -> None:
        seen.add(fname)
        for n, text in enumerate(read_shader(fname, dirs).splitlines(), 1):
            m = _INCLUDE.match(text)
            if m:
                if m.group(1) not in seen:
                    add(m.group(1))
                continue
            lines.append(text)
            origin.append((fname, n))

    add(name)
    ints = {k: int(v) for k, v in (defines or {}).items() if re.fullmatch(r"-?\d+", str(v))}
    while any(_UNROLL.match(t) for t in lines):   # nested loops: the outer one first
        lines, origin = _unroll(lines, origin, ints)
    return Source("\n".join(lines) + "\n", tuple(origin))


def _unroll(lines: list[str], origin: list[tuple[str, int]], ints: dict[str, int]) -> tuple[list, list]:
    """Each loop after a ``#pragma unroll`` line — ``for (int k = A; k < B; ++k)`` (or ``<=``),
    A and B integer literals or integer #defines, then a braced body or a one-line statement
    without braces — written out once per k as ``do { const int k = …; body } while (false);``
    (``continue`` keeps its meaning; ``break`` is refused): every index by k becomes a constant
    expression. NVIDIA keeps a local array that a loop variable indexes in memory that holds
    doubles as float32 (README, "glsim check": reads round to float32); constant indices keep
    it in registers, bit for bit. Origins are kept, so driver logs name the loop's own lines."""
    out: list[str] = []
    where: list[tuple[str, int]] = []
    i = 0
    while i < len(lines):
        m = _INT_DEFINE.match(lines[i])
        if m and ints.setdefault(m.group(1), int(m.group(2))) != int(m.group(2)):
            ints[m.group(1)] = None   # two values (#ifdef branches): not a bound the loader can know
        if not _UNROLL.match(lines[i]):
            out.append(lines[i])
            where.append(origin[i])
            i += 1
            continue
        f, n = origin[i]
        m = _FOR.match(lines[i + 1]) if i + 1 < len(lines) else None
        if m is None:
            raise ShaderError(f"{f}:{n}: #pragma unroll must precede a loop 'for (int k = A; k < B; ++k)'")
        indent, var, a, op, b, rest = m.groups()
        lo, hi = (int(v) if v.lstrip("-").isdigit() else ints.get(v) for v in (a, b))
        if lo is None or hi is None:
            raise ShaderError(f"{f}:{n}: #pragma unroll: the bound {a if lo is None else b} is not an integer literal "
                              "or a #define of one value")
        hi += op == "<="
        try:
            body, body_origin, end = _loop_body(lines, origin, i + 1, rest.strip())
        except (ValueError, IndexError):
            raise ShaderError(f"{f}:{n}: #pragma unroll: a loop body of more than one line needs braces") from None
        if any(re.search(r"\bbreak\b", t.split("//")[0]) for t in body):
            raise ShaderError(f"{f}:{n}: #pragma unroll: 'break' in the loop (unrolled copies cannot leave the loop)")
        for k in range(lo, hi):
            out.append(f"{indent}do {{ const int {var} = {k};")
            where.append(origin[i + 1])
            out += body
            where += body_origin
            out.append(f"{indent}}} while (false);")
            where.append(body_origin[-1])
        i = end
    return out, where


def _loop_body(lines, origin, i, rest):
    """The body of the loop whose header is lines[i] (``rest``: the header line after the
    closing parenthesis): its lines without the outer braces, their origins, and the index of
    the first line after it."""
    if not rest.strip():
        i += 1
        rest = lines[i].strip()
    if not rest.startswith("{"):
        if rest.startswith("#") or not rest.split("//")[0].rstrip().endswith(";"):
            raise ValueError("a loop body of more than one line needs braces")
        return [lines[i] if lines[i].strip() == rest else rest], [origin[i]], i + 1
    depth, body, where, first = 0, [], [], True
    while True:
        text = rest if first else lines[i]
        code = text.split("//")[0]
        for j, c in enumerate(code):
            depth += (c == "{") - (c == "}")
            if depth == 0 and c == "}":
                inner = code[:j].lstrip()[1:] if first else code[:j]
                body.append(inner)
                where.append(origin[i])
                return body, where, i + 1
        body.append(code.lstrip()[1:] if first else text)
        where.append(origin[i])
        first = False
        i += 1


def translate_log(log: str, sources: dict[str, Source]) -> str:
    """Rewrite a driver log so each line number names the shader file and line."""
    out = []
    stage = None
    for line in log.splitlines():
        key = line.strip().lower()
        if key in sources:
            stage = key
        m = _LOG_LINE.match(line)
        if m and stage:
            out.append(f"{sources[stage].locate(int(m.group(1)))}: {m.group(2)}")
        elif line.strip() and set(line.strip()) != {"="}:
            out.append(line)
    return "\n".join(out)


class ProgramCache:
    """Compiles programs once per (files, defines) and GL context: the packaged shaders' programs
    are shared by every cache on the same context (kept in ``ctx.extra``, freed with the
    context), so several renderers on one context compile each program once (pyrender keys its
    cache by context and defines). ``dirs`` (tests' own shaders) are searched before the packaged
    ones; such a cache keeps its programs to itself and frees them in :meth:`release`.
    ``compiled`` lists what this cache was asked for, in order (first requests only)."""

    def __init__(self, ctx, dirs: tuple = ()):
        self.ctx = ctx
        self.dirs = tuple(dirs)
        self._own = bool(self.dirs)
        self._programs: dict = {} if self._own else _shared(ctx)
        self._asked: set = set()
        self._found: dict = {}
        self.compiled: list[tuple[tuple[str, ...], dict]] = []

    def _build(self, stages: tuple[tuple[str, str], ...], defines: dict, make):
        """The program of ``stages`` ((stage, file) pairs) and ``defines``, compiled on first
        request; found again by the defines in the caller's order (no sorting) after that."""
        found = self._found.get((stages, tuple(defines.items())))
        if found is not None:
            return found
        key = (stages, tuple(sorted(defines.items())))
        if key not in self._programs:
            sources = {stage: assemble(f, defines, self.dirs) for stage, f in stages}
            try:
                prog = make(**{s: src.text for s, src in sources.items()})
            except Exception as exc:
                files = ", ".join(f for _, f in stages)
                raise ShaderError(f"GLSL program ({files}) failed to build with defines "
                                  f"{dict(defines)}:\n{translate_log(str(exc), sources)}") from None
            _check_samplers(prog, stages)
            self._programs[key] = prog
        if key not in self._asked:
            self._asked.add(key)
            self.compiled.append((tuple(f for _, f in stages), dict(defines)))
        prog = self._found[(stages, tuple(defines.items()))] = self._programs[key]
        return prog

    def program(self, vertex: str, fragment: str, defines: dict | None = None, geometry: str | None = None):
        """A vertex + fragment program, with a geometry shader between them if ``geometry``."""
        stages = (("vertex_shader", vertex), *((("geometry_shader", geometry),) if geometry else ()),
                  ("fragment_shader", fragment))
        return self._build(stages, defines or {}, self.ctx.program)

    def compute(self, name: str, defines: dict | None = None):
        """A compute shader."""
        return self._build((("source", name),), defines or {},
                           lambda source: self.ctx.compute_shader(source))

    def entry(self, name: str, defines: dict | None = None):
        """The program of the entry file ``name``: a compute shader (.comp), or a fragment shader
        after the vertex (and geometry) shader :data:`PROGRAMS` gives it."""
        if name.endswith(".comp"):
            return self.compute(name, defines)
        vertex, *geometry = PROGRAMS[name]
        return self.program(vertex, name, defines, geometry[0] if geometry else None)

    def name_of(self, prog) -> str:
        """The file of ``prog``'s last stage (fragment or compute shader), "?" if not built here."""
        for (stages, _), p in self._programs.items():
            if p is prog:
                return stages[-1][1]
        return "?"

    def release(self) -> None:
        """Free this cache's own programs (the shared ones live as long as the context)."""
        if self._own:
            for prog in self._programs.values():
                prog.release()
            self._programs.clear()
        self._asked.clear()
        self._found.clear()


def _check_samplers(prog, stages) -> None:
    """Every sampler of ``prog`` named in the binding table reads its fixed unit (frames bind
    the textures there and never set the uniform)."""
    for name, unit in bindings.SAMPLERS.items():
        u = prog.get(name, None)
        if u is not None and u.value != unit:
            files = ", ".join(f for _, f in stages)
            raise ShaderError(f"GLSL program ({files}): sampler {name} reads texture unit {u.value}, not its unit "
                              f"{unit}; declare it as layout(binding = {bindings.sampler_define(name)}) uniform … {name};")


def _shared(ctx) -> dict:
    """The packaged programs of ``ctx``, shared by its caches (in ``ctx.extra``)."""
    if not isinstance(ctx.extra, dict):
        ctx.extra = {}
    return ctx.extra.setdefault("glsim.programs", {})
