"""The README's and docs' generated figures (``python -m tools.docs [--check]``): :mod:`tools.docs.regions`
finds and rewrites the regions; the generators live by topic in :mod:`~tools.docs.accuracy`,
:mod:`~tools.docs.verify`, :mod:`~tools.docs.calib` and :mod:`~tools.docs.bench`."""
