"""Training sets for learned DIC: a library spec with ``[training]`` writes WebDataset shards of
samples (a variant's cameras at step 0 and at a load step, and the per-pixel labels between
them) instead of variant folders (``glsim library SPEC -o DIR``; docs/training.md).

Modules: :mod:`.spec` (the [training] table, shards cut from the sample's size), :mod:`.labels`
(the labels of a pair), :mod:`.shards` (deterministic tar members), :mod:`.worker` (one shard per
task), :mod:`.runner` (directory rules, resume, verify), :mod:`.loader` (reading shards back),
:mod:`.cli` (the library command's training mode).
"""
