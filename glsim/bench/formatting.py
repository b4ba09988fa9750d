"""Numbers as the results files and the generated README/docs figures print them: every benchmark
report and every generator of ``glsim docs`` formats through these."""
from __future__ import annotations


def sig(x: float | None, digits: int = 2, *, trailing_zeros: bool = True) -> str:
    """``x`` to ``digits`` significant digits, plainly for 1e-3 ≤ |x| < 1e4, else as 1.2e-05 → 1.2e-5;
    "–" for None. ``trailing_zeros=False`` drops the zeros a plain figure ends in (0.50 → 0.5)."""
    if x is None:
        return "–"
    if x == 0:
        return "0"
    if 1e-3 <= abs(x) < 1e4:
        return f"{x:#.{digits}g}".rstrip(".") if trailing_zeros else f"{x:.{digits}g}"
    m, e = f"{x:.{digits - 1}e}".split("e")
    return f"{m}e{int(e)}"


def ratio(a: float, b: float) -> str:
    """``a / b`` as a factor: 2 significant digits below 10 (0.53×, 2.1×), whole above (14×)."""
    return f"{a / b:.2g}×" if a / b < 10 else f"{a / b:.0f}×"


def num(x: float | None, fmt: str = ".3g", missing: str = "–") -> str:
    """``x`` in the format ``fmt`` (a format spec: ".3g", ".2e", ".0%"), ``missing`` for None."""
    return missing if x is None else format(x, fmt)
