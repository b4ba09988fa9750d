"""Repository tooling, run from the repository root (``python -m tools.…``); not part of the glsim wheel."""
