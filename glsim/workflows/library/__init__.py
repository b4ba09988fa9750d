"""Image libraries: one spec (base scene + ``[vary]``) in, many variants' images, compact truth
and a manifest out — resumable, in parallel processes or on a Dask cluster (``glsim library``).

Modules: :mod:`.spec` (reading and expanding specs), :mod:`.keys` (what variants share: mesh,
reference and truth keys), :mod:`.worker` (rendering a task, one
renderer per worker thread), :mod:`.writer` (encoding and writing in a writer process),
:mod:`.lifeline` (children that end with their parent), :mod:`.manifest` (manifest.csv and
library.json), :mod:`.runner` (directory rules, pools, resume), :mod:`.audit` (which files are
good, verify), :mod:`.cli` (the command line). The names below are imported on first use, so
that a writer process, which imports :mod:`.writer` only, loads no renderer.
"""
_NAMES = {"Summary": "runner", "run": "runner", "verify": "audit",
          "LibraryPlan": "spec", "SpecError": "spec", "expand": "spec", "load_plan": "spec"}
__all__ = sorted(_NAMES)


def __getattr__(name: str):
    if name in _NAMES:
        import importlib
        return getattr(importlib.import_module(f"{__name__}.{_NAMES[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
