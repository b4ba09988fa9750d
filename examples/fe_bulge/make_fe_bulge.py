"""Solve the paper's bulge test (Table 2) with scikit-fem and write it as Abaqus .inp + CSV files.

Model: linear Kirchhoff plate bending of a clamped circular plate, R = 50 mm, t = 3 mm,
E = 210 GPa, ν = 0.3, uniform pressure p on its back face, discretised with C¹ Argyris
triangles (scikit-fem's ``ElementTriArgyris``, quintic) on a polygonal disc:

    find w with w = ∂w/∂n = 0 on the boundary such that
    ∫ M(w) : K(v) dA = ∫ p v dA  for all admissible v,
    K = ∇∇w, M = t³/12 · E/(1+ν) · (K + ν/(1−ν) tr(K) I)       (D = E t³ / (12 (1 − ν²))).

Clamping: the Argyris degrees of freedom w, ∂w/∂x, ∂w/∂y at every boundary vertex and ∂w/∂n
at every boundary edge midpoint are zero (the vertex second derivatives stay free).

Mesh: ``N_RINGS`` concentric rings of nodes at radii k·R/N_RINGS, ring k holding 6k nodes at
equal angles; the rings are joined by triangles as in a subdivided hexagon (6·N_RINGS²
triangles, 1 + 3·N_RINGS·(N_RINGS + 1) nodes; the boundary is the inscribed 6·N_RINGS-gon).
The same triangles are written as linear S3 shells (glsim stores them as collapsed Q4s), so the
export needs no interpolation: the Argyris vertex degrees of freedom *are* the nodal values of
w and ∇w.

What is written, per node (mm), is the motion of the viewed surface fibre, the convex face
t/2 from the mid-plane, of a plate bulging towards −z (the cameras), as glsim's analytic
``bulge_displacements``:  u_x, u_y = −(t/2)·∂w/∂x, −(t/2)·∂w/∂y (i.e. u_r = −(t/2)·dw/dr,
outwards near the centre) and u_z = −w. Node coordinates are the plate's mid-plane z = 0,
like glsim's built-in disc, so the scene's placement is the one of ``examples/bulge.toml``.

Two load cases, each ``N_STEPS`` equal pressure steps from 0 (one linear static solve each):

- ``u_step{k}.csv``:  Table 2's p = 11.9 MPa. Linear theory: w0 = pR⁴/(64D) = 2.238 mm.
- ``u5mm_step{k}.csv``: p = 64·D·(5 mm)/R⁴ = 26.585 MPa, *linear theory scaled to the
  paper's 5 mm bulge* (the paper's 5 mm needed a non-linear model: at 11.9 MPa the linear
  edge bending stress 6·(pR²/8)/t² ≈ 2.5 GPa is far beyond yield).

Run ``python examples/fe_bulge/make_fe_bulge.py`` to regenerate the committed files (needs
scikit-fem, ``pip install 'glsim[fe]'``; reading them does not), ``--convergence`` to print the
mesh-convergence study of docs/fe_bulge.md.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

RADIUS, THICKNESS = 50.0, 3.0            # mm
YOUNG, POISSON = 210000.0, 0.3           # MPa (= N/mm²), –
RIGIDITY = YOUNG * THICKNESS ** 3 / (12 * (1 - POISSON ** 2))   # D, N·mm
P_TABLE2 = 11.9                          # MPa, the paper's Table 2
P_5MM = 64 * RIGIDITY * 5.0 / RADIUS ** 4  # MPa: 5 mm centre deflection in linear theory
LOAD_CASES = (("u_step", P_TABLE2), ("u5mm_step", P_5MM))  # file prefix, full pressure
N_RINGS = 16
N_STEPS = 4
OUT = Path(__file__).resolve().parent


def analytic_deflection(r, pressure: float) -> np.ndarray:
    """Linear Kirchhoff deflection (mm) of the clamped circular plate: w0·(1 − r²/R²)², w0 = pR⁴/(64D)."""
    w0 = pressure * RADIUS ** 4 / (64 * RIGIDITY)
    return w0 * np.clip(1 - (np.asarray(r) / RADIUS) ** 2, 0.0, None) ** 2


def analytic_slope(r, pressure: float) -> np.ndarray:
    """dw/dr (–) of analytic_deflection."""
    w0 = pressure * RADIUS ** 4 / (64 * RIGIDITY)
    r = np.asarray(r)
    return -4 * w0 * r / RADIUS ** 2 * np.clip(1 - (r / RADIUS) ** 2, 0.0, None)


def _number(x: float, decimals: int) -> str:
    """Fixed-point text without a '-0.000…'."""
    text = f"{x:.{decimals}f}"
    return f"{0.0:.{decimals}f}" if float(text) == 0 else text


def ring_mesh(n_rings: int = N_RINGS) -> tuple[list[tuple[str, str]], np.ndarray, np.ndarray]:
    """The disc mesh: node coordinate texts (x, y) as written, triangles (M,3) 0-based
    counter-clockwise seen from +z, and the 0-based boundary nodes (the outer ring)."""
    xy = [("0.000000", "0.000000")]
    first = [0]                                   # index of each ring's node at angle 0
    for k in range(1, n_rings + 1):
        first.append(len(xy))
        for i in range(6 * k):
            angle = 2 * np.pi * i / (6 * k)
            r = RADIUS * k / n_rings
            xy.append((_number(r * np.cos(angle), 6), _number(r * np.sin(angle), 6)))
    triangles = [(0, 1 + s, 1 + (s + 1) % 6) for s in range(6)]
    for k in range(2, n_rings + 1):
        def inner(j, k=k):
            return first[k - 1] + j % (6 * (k - 1))

        def outer(i, k=k):
            return first[k] + i % (6 * k)
        for s in range(6):                        # one sixth of the annulus: 2k − 1 triangles
            a, b = s * (k - 1), s * k
            triangles += [(outer(b + i), outer(b + i + 1), inner(a + i)) for i in range(k)]
            triangles += [(inner(a + j), outer(b + j + 1), inner(a + j + 1)) for j in range(k - 1)]
    return xy, np.array(triangles, dtype=np.int64), np.arange(first[-1], len(xy))


def solve_plate(nodes: np.ndarray, triangles: np.ndarray, pressures, element: str = "argyris"):
    """Clamped Kirchhoff plate under each uniform pressure (MPa) on the mesh (mm).

    Returns, per pressure, (w, ∂w/∂x, ∂w/∂y) at the nodes: the Argyris vertex degrees of
    freedom. With element="morley" (the non-conforming quadratic of scikit-fem's Kirchhoff
    example, for comparison) the slopes are the element gradients averaged at each vertex.
    """
    from skfem import (Basis, BilinearForm, ElementTriArgyris, ElementTriMorley, LinearForm, MeshTri, asm,
                       condense, solve)
    from skfem.helpers import dd, ddot, eye, trace

    mesh = MeshTri(np.ascontiguousarray(nodes.T, dtype=np.float64), np.ascontiguousarray(triangles.T))

    @BilinearForm
    def bending(u, v, _):
        def moment(curvature):  # t³/12 · plane-stress C : K
            return THICKNESS ** 3 / 12 * YOUNG / (1 + POISSON) * (
                curvature + POISSON / (1 - POISSON) * eye(trace(curvature), 2))
        return ddot(moment(dd(u)), dd(v))

    @LinearForm
    def unit_pressure(v, _):
        return 1.0 * v

    # Degree 6 integrates the Argyris (quintic) stiffness and load exactly on straight triangles.
    basis = Basis(mesh, ElementTriArgyris() if element == "argyris" else ElementTriMorley(), intorder=6)
    stiffness, load = asm(bending, basis), asm(unit_pressure, basis)
    boundary = basis.get_dofs()
    clamped = boundary.all(["u", "u_x", "u_y", "u_n"]) if element == "argyris" else boundary.all()
    results = []
    for p in pressures:
        x = solve(*condense(stiffness, p * load, D=clamped))
        if element == "argyris":
            results.append(tuple(x[basis.nodal_dofs[i]] for i in range(3)))
        else:
            results.append((x[basis.nodal_dofs[0]], *_vertex_average(mesh, x)))
    return results


def _vertex_average(mesh, x):
    """Morley only: element gradients at each vertex, averaged over the vertex's elements."""
    from skfem import Basis, ElementTriMorley

    corners = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    at_corners = Basis(mesh, ElementTriMorley(), quadrature=(corners, np.ones(3) / 6))
    grad = at_corners.interpolate(x).grad             # (2, elements, 3 corners)
    sums = np.zeros((2, mesh.nvertices))
    counts = np.bincount(mesh.t.ravel(), minlength=mesh.nvertices)
    for c in range(3):
        for d in range(2):
            np.add.at(sums[d], mesh.t[c], grad[d][:, c])
    return sums[0] / counts, sums[1] / counts


def surface_displacement(w, w_x, w_y) -> np.ndarray:
    """(N,3) mm: the viewed (convex) face's fibre of a plate bulging by w towards −z."""
    return np.stack([-THICKNESS / 2 * w_x, -THICKNESS / 2 * w_y, -w], axis=1)


def write_inp(path: Path, xy, triangles: np.ndarray, boundary: np.ndarray) -> None:
    lines = ["*HEADING",
             "glsim example: FE bulge test (paper Table 2), clamped circular plate R = 50 mm, t = 3 mm, mm",
             "** Linear Kirchhoff plate, E = 210000 MPa, nu = 0.3, solved with scikit-fem (Argyris triangles)",
             "** by examples/fe_bulge/make_fe_bulge.py; these S3 triangles are its mesh, z = mid-plane.",
             "** Displacements of the viewed (convex, -z) face per step: u_step*.csv, u5mm_step*.csv.",
             "*NODE"]
    lines += [f"{i + 1}, {x}, {y}, 0" for i, (x, y) in enumerate(xy)]
    lines += ["*ELEMENT, TYPE=S3, ELSET=PLATE"]
    lines += [f"{e + 1}, {a + 1}, {b + 1}, {c + 1}" for e, (a, b, c) in enumerate(triangles)]
    lines += ["*NSET, NSET=CLAMPED"]
    labels = [str(i + 1) for i in boundary]
    lines += [", ".join(labels[i:i + 16]) for i in range(0, len(labels), 16)]
    path.write_text("\n".join(lines) + "\n")


def write_csv(path: Path, u: np.ndarray) -> None:
    rows = ["label;ux;uy;uz"] + [f"{i + 1};" + ";".join(_number(v, 7) for v in row) for i, row in enumerate(u)]
    path.write_text("\n".join(rows) + "\n")


def main() -> None:
    xy, triangles, boundary = ring_mesh()
    nodes = np.array(xy, dtype=np.float64)        # solve on exactly the written coordinates
    OUT.mkdir(exist_ok=True)
    write_inp(OUT / "bulge.inp", xy, triangles, boundary)
    r = np.hypot(nodes[:, 0], nodes[:, 1])
    steps = [(f"{prefix}{k}.csv", full * k / N_STEPS) for prefix, full in LOAD_CASES for k in range(1, N_STEPS + 1)]
    for (name, p), fields in zip(steps, solve_plate(nodes, triangles, [p for _, p in steps])):
        write_csv(OUT / name, surface_displacement(*fields))
        w, wa = fields[0], analytic_deflection(r, p)
        print(f"{name:15s} p = {p:7.4f} MPa  w(0) FE = {w[0]:.5f} mm, analytic = {wa[0]:.5f} mm "
              f"({w[0] / wa[0] - 1:+.3%}), max |w − w_analytic| = {np.abs(w - wa).max():.2e} mm")


def convergence(element: str = "argyris", rings=(4, 8, 12, 16, 24)) -> None:
    """Print the centre-deflection, field and slope errors against linear theory per mesh."""
    print(f"{element}: rings nodes triangles  w(0) mm   rel. error  max|w−wa|/w0  max|dw/dr err|/max|dw/dr|")
    w0 = analytic_deflection(0.0, P_TABLE2)
    for n in rings:
        xy, triangles, _ = ring_mesh(n)
        nodes = np.array(xy, dtype=np.float64)
        (w, wx, wy), = solve_plate(nodes, triangles, [P_TABLE2], element)
        r = np.hypot(nodes[:, 0], nodes[:, 1])
        e_r = np.divide(nodes, r[:, None], out=np.zeros_like(nodes), where=r[:, None] > 0)
        slope = analytic_slope(r, P_TABLE2)
        slope_err = np.hypot(wx - slope * e_r[:, 0], wy - slope * e_r[:, 1]).max() / np.abs(slope).max()
        print(f"{'':9}{n:5d} {len(nodes):5d} {len(triangles):9d}  {w[0]:.5f}  {w[0] / w0 - 1:+.3e}"
              f"   {np.abs(w - analytic_deflection(r, P_TABLE2)).max() / w0:.2e}      {slope_err:.2e}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--convergence", action="store_true", help="print the mesh-convergence study instead")
    parser.add_argument("--element", choices=("argyris", "morley"), default="argyris",
                        help="element of the convergence study (morley: scikit-fem's Kirchhoff example)")
    args = parser.parse_args()
    convergence(args.element) if args.convergence else main()
