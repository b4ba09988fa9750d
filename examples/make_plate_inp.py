"""Write the tiny Abaqus plate of ``plate_inp/``: a 40 × 30 mm plate of 8 × 6 S4R shells in its
XY plane (mm, centred at the origin) and two load steps of a uniaxial strain field as
``label;ux;uy;uz`` CSV files (step k: εxx = 0.002·k, εyy = −0.3·εxx, uz = 0).

Run ``python examples/make_plate_inp.py`` to regenerate the committed files. Node labels
start at 101 and element labels at 1001, so loaders must use the file's labels.
"""
from pathlib import Path

WIDTH, HEIGHT, NX, NY = 40.0, 30.0, 8, 6
STRAIN, POISSON = 0.002, 0.3
OUT = Path(__file__).resolve().parent / "plate_inp"


def nodes():
    """(label, x, y) row by row from the bottom-left corner."""
    for j in range(NY + 1):
        for i in range(NX + 1):
            yield 101 + j * (NX + 1) + i, -WIDTH / 2 + WIDTH * i / NX, -HEIGHT / 2 + HEIGHT * j / NY


def elements():
    """(label, n1, n2, n3, n4): counter-clockwise seen from +z."""
    for j in range(NY):
        for i in range(NX):
            n1 = 101 + j * (NX + 1) + i
            yield 1001 + j * NX + i, n1, n1 + 1, n1 + NX + 2, n1 + NX + 1


def main() -> None:
    OUT.mkdir(exist_ok=True)
    lines = ["*HEADING", "glsim example: 40 x 30 mm plate, 8 x 6 S4R, mm", "*NODE"]
    lines += [f"{n}, {x:.6g}, {y:.6g}, 0" for n, x, y in nodes()]
    lines += ["*ELEMENT, TYPE=S4R, ELSET=PLATE"]
    lines += [", ".join(map(str, e)) for e in elements()]
    (OUT / "plate.inp").write_text("\n".join(lines) + "\n")
    for k in (1, 2):
        exx = STRAIN * k
        rows = ["label;ux;uy;uz"] + [f"{n};{exx * x:.9g};{-POISSON * exx * y:.9g};0" for n, x, y in nodes()]
        (OUT / f"u_step{k}.csv").write_text("\n".join(rows) + "\n")


if __name__ == "__main__":
    main()
