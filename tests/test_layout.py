"""The package layout the README's "Layout" section states: layers import only downwards (or
within their own folder), no module imports itself through others (no circles, lazy imports
included), only the GL backend imports moderngl, and nothing in the package imports the
repository's tools/ (which the wheel leaves out)."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "glsim"
LAYERS = ("errors", "limits", "scene", "io", "imaging", "effects", "backends", "compose", "render", "workflows", "bench",
          "check", "dic", "cli")


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)   # `from pkg import module`
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return names


def _layer(module: str) -> str:
    return module.split(".")[1] if module.count(".") else ""


def test_layers_import_only_downwards_and_gl_alone_imports_moderngl():
    upward, moderngl, tools = [], [], []
    for f in ROOT.rglob("*.py"):
        mod = ".".join(("glsim",) + f.relative_to(ROOT).with_suffix("").parts)
        own = _layer(mod) or "cli"
        for name in _imports(f):
            if name.split(".")[0] == "moderngl" and not mod.startswith("glsim.backends.gl"):
                moderngl.append(mod)
            if name.split(".")[0] == "tools":
                tools.append(f"{mod} imports {name}")
            if name.startswith("glsim.") and LAYERS.index(_layer(name)) > LAYERS.index(own.removesuffix(".py")):
                upward.append(f"{mod} imports {name}")
    assert not moderngl, f"moderngl imported outside glsim.backends.gl: {moderngl}"
    assert not tools, f"the package imports the repository's tools/, which the wheel leaves out: {tools}"
    assert not upward, "imports against the layer order " + " → ".join(LAYERS) + ":\n" + "\n".join(sorted(upward))


def test_no_import_circles():
    mods = {".".join(("glsim",) + f.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__"): f
            for f in ROOT.rglob("*.py")}
    graph = {m: {n for n in _imports(f) if n in mods and n != m and not n.startswith(m + ".")}
             for m, f in mods.items()}
    state, cycles = {}, []

    def visit(m, path):
        state[m] = 1
        for n in graph[m]:
            if state.get(n) == 1:
                cycles.append(path[path.index(n):] + [n])
            elif n not in state:
                visit(n, path + [n])
        state[m] = 2
    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    assert not cycles, "import circles:\n" + "\n".join(" → ".join(c) for c in cycles)
