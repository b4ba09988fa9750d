"""Writing a matplotlib figure as a results file: laid out, written atomically, closed."""
from __future__ import annotations

from pathlib import Path

from glsim.io import images as io


def save_figure(fig, path: str | Path, dpi: int) -> Path:
    """Lay out, write atomically as PNG and close a matplotlib figure."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(path)
    with io.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return path
