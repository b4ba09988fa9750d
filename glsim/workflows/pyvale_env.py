"""Where the independent DIC lives: pyvale in its own environment (``.venv-verify``; pyvale pins
opencv-python, so it never enters glsim's) and the scripts of the source checkout that drive it
(``verify/``, not in the wheel). ``glsim verify``, ``glsim verify sweep`` and ``glsim design`` run them."""
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PYTHON = REPO / ".venv-verify" / "bin" / "python"
STEREO_SCRIPT = REPO / "verify" / "dic.py"      # pyvale's calculate_3d
PLANAR_SCRIPT = REPO / "verify" / "dic2d.py"    # pyvale's calculate_2d
SETUP_HINT = "make .venv-verify/.pyvale-installed (about 2 GB, a few minutes; `make sweep` makes it too)"
