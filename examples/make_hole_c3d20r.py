"""Write the open-hole plate of ``hole_c3d20r/``: an Abaqus model of 20-node reduced-integration
bricks (C3D20R), the quadratic solid most specimen models use, with two load steps of
displacements as ``label;ux;uy;uz`` CSV files.

The plate is 60 × 40 × 2 mm (mm, centred at the origin, faces at z = ±1) with a central
hole of radius 6 mm, meshed as an O-grid of 20 × 5 bricks around the hole, one through the
thickness, graded towards the hole, the outline's corners on nodes; mid-side nodes sit at the parametric middles, so the hole
is a quadratic approximation of the circle, as a mesher would make it. The displacements are
Kirsch's plane-stress solution for a hole in an infinite plate under uniaxial tension σ along
x (σ = 100 and 200 MPa, aluminium E = 70 GPa, ν = 0.33), with the through-thickness strain
εzz = −ν (σrr + σθθ) / E: a closed form prescribed at the nodes, not an FE solve (the plate is
finite, so it is not the plate's exact solution; it is smooth and of the right size, ≈ 1 px of
displacement at the example's resolution).

Run ``python examples/make_hole_c3d20r.py`` to regenerate the committed files.
"""
from pathlib import Path

import numpy as np

WIDTH, HEIGHT, THICK, RADIUS = 60.0, 40.0, 2.0, 6.0
N_THETA, N_R, GRADING = 20, 5, 1.4   # 40 half steps of 5 mm round the outline: corners on nodes
E, NU, STRESSES = 70000.0, 0.33, (100.0, 200.0)
OUT = Path(__file__).resolve().parent / "hole_c3d20r"


def used(i: int, j: int, k: int) -> bool:
    """Grid points (half steps in θ, r, z) a C3D20 needs: no face or body centres."""
    return (i % 2 == 0 or j % 2 == 0) if k != 1 else (i % 2 == 0 and j % 2 == 0)


def outline(p: float) -> np.ndarray:
    """The plate's outline at arc length ``p`` (mm) from (W/2, 0), counter-clockwise."""
    w, h = WIDTH / 2, HEIGHT / 2
    for length, start, direction in ((h, (w, 0), (0, 1)), (2 * w, (w, h), (-1, 0)), (2 * h, (-w, h), (0, -1)),
                                     (2 * w, (-w, -h), (1, 0)), (h, (w, -h), (0, 1))):
        if p <= length + 1e-12:
            return np.add(start, np.multiply(direction, p))
        p -= length
    raise ValueError("past the outline")


def grid() -> dict:
    """(i, j, k) → (label, x, y, z): i around the hole (periodic, the outline's corners on
    element corners), j outwards, k through the thickness."""
    step = 2 * (WIDTH + HEIGHT) / (2 * N_THETA)
    points, label = {}, 1
    for k in range(3):
        for j in range(2 * N_R + 1):
            for i in range(2 * N_THETA):
                if not used(i, j, k):
                    continue
                edge = outline(i * step)
                hole = RADIUS * edge / np.hypot(*edge)
                x, y = hole + (edge - hole) * (j / (2 * N_R)) ** GRADING
                points[i, j, k] = (label, x, y, THICK * (k / 2 - 0.5))
                label += 1
    return points


def elements(points: dict) -> list[list[int]]:
    """C3D20 connectivity (Abaqus order): bottom corners counter-clockwise seen from +z, top
    corners, bottom and top mid-edges, then the vertical mid-edges."""
    out = []
    for e in range(N_THETA):
        i0, i1, i2 = 2 * e, 2 * e + 1, (2 * e + 2) % (2 * N_THETA)
        for f in range(N_R):
            j0, j1, j2 = 2 * f, 2 * f + 1, 2 * f + 2
            corners = [(i0, j0), (i0, j2), (i2, j2), (i2, j0)]
            mids = [(i0, j1), (i1, j2), (i2, j1), (i1, j0)]
            ids = [points[c + (0,)][0] for c in corners] + [points[c + (2,)][0] for c in corners]
            ids += [points[m + (0,)][0] for m in mids] + [points[m + (2,)][0] for m in mids]
            ids += [points[c + (1,)][0] for c in corners]
            out.append(ids)
    return out


def kirsch(x: np.ndarray, y: np.ndarray, z: np.ndarray, sigma: float) -> np.ndarray:
    """Displacements (mm) of the plane-stress Kirsch solution, plus εzz·z."""
    r, t = np.hypot(x, y), np.arctan2(y, x)
    mu, kappa = E / (2 * (1 + NU)), (3 - NU) / (1 + NU)
    a2, c2, s2 = RADIUS ** 2, np.cos(2 * t), np.sin(2 * t)
    ur = sigma / (4 * mu) * (r * ((kappa - 1) / 2 + c2) + a2 / r * (1 + (1 + kappa) * c2) - a2 ** 2 / r ** 3 * c2)
    ut = sigma / (4 * mu) * ((1 - kappa) * a2 / r - r - a2 ** 2 / r ** 3) * s2
    ezz = -NU / E * sigma * (1 - 2 * a2 / r ** 2 * c2)
    return np.stack([ur * np.cos(t) - ut * np.sin(t), ur * np.sin(t) + ut * np.cos(t), ezz * z], 1)


def main() -> None:
    OUT.mkdir(exist_ok=True)
    points = grid()
    nodes = sorted(points.values())
    lines = ["*HEADING", f"glsim example: {WIDTH:g} x {HEIGHT:g} x {THICK:g} mm plate, hole R{RADIUS:g}, C3D20R, mm",
             "*NODE"]
    lines += [f"{n}, {x:.9g}, {y:.9g}, {z:.9g}" for n, x, y, z in nodes]
    lines += ["*ELEMENT, TYPE=C3D20R, ELSET=PLATE"]
    for label, ids in enumerate(elements(points), 1):        # at most 16 labels per line, then continue
        row = [label, *ids]
        lines += [", ".join(map(str, row[:16])) + ",", ", ".join(map(str, row[16:]))]
    (OUT / "plate.inp").write_text("\n".join(lines) + "\n")
    xyz = np.array([p[1:] for p in nodes])
    for k, sigma in enumerate(STRESSES, 1):
        u = kirsch(xyz[:, 0], xyz[:, 1], xyz[:, 2], sigma)
        rows = ["label;ux;uy;uz"] + [f"{n[0]};{a:.9g};{b:.9g};{c:.9g}" for n, (a, b, c) in zip(nodes, u)]
        (OUT / f"u_step{k}.csv").write_text("\n".join(rows) + "\n")


if __name__ == "__main__":
    main()
