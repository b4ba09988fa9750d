"""Image libraries: one spec (base scene + ``[vary]``) in, many variants' images, compact truth
and a manifest out — resumable, in parallel processes or on a Dask cluster (``glsim library``).

Modules: :mod:`.spec` (reading and expanding specs), :mod:`.worker` (rendering a task, one
renderer per worker thread), :mod:`.manifest` (manifest.csv and library.json), :mod:`.runner`
(directory rules, pools, resume, verify), :mod:`.cli` (the command line).
"""
from glsim.workflows.library.runner import Summary, run, verify
from glsim.workflows.library.spec import Plan, SpecError, expand, load_plan

__all__ = ["Plan", "SpecError", "Summary", "expand", "load_plan", "run", "verify"]
