"""A library's or training set's index files (library.json, training.json, manifest.csv) are
bounded before they are read: a planted file larger than any glsim writes (a sparse file: no disk
used) is refused by its size, quickly, without reading it — glsim treats the directory as holding
no library / a damaged manifest, as it does any index it cannot trust."""
import os

import pytest

from glsim.limits import MAX_INDEX_BYTES, read_bounded
from glsim.workflows.library import manifest as mf
from glsim.workflows.training import runner as tr


def _sparse(path, size):
    with open(path, "wb") as f:
        f.truncate(size)
    return path


def test_read_bounded_refuses_past_the_limit_before_reading(tmp_path):
    path = _sparse(tmp_path / "big", MAX_INDEX_BYTES + 1)
    with pytest.raises(OSError, match="more than the"):
        read_bounded(path)
    small = tmp_path / "small"
    small.write_bytes(b"x" * 10)
    assert read_bounded(small, limit=10) == b"x" * 10
    with pytest.raises(OSError):
        read_bounded(small, limit=9)


@pytest.mark.process
def test_a_fifo_is_not_read_past_the_limit(tmp_path):
    """Not a regular file (size 0 by fstat): the read itself stops one byte past the limit."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    pid = os.fork()
    if pid == 0:                     # the writer: more than the limit, then gone
        try:
            with open(fifo, "wb") as f:
                f.write(b"y" * 64)
        finally:
            os._exit(0)
    try:
        with pytest.raises(OSError, match="more than the 16"):
            read_bounded(fifo, limit=16)
    finally:
        os.waitpid(pid, 0)


def test_oversized_index_files_are_damaged_not_read(tmp_path):
    _sparse(tmp_path / mf.LIBRARY, MAX_INDEX_BYTES + 1)
    assert mf.read_library_info(tmp_path) is None
    _sparse(tmp_path / tr.INFO, MAX_INDEX_BYTES + 1)
    assert tr.read_info(tmp_path) is None
    _sparse(tmp_path / tr.MANIFEST, MAX_INDEX_BYTES + 1)
    assert tr.read_manifest(tmp_path) == {}
    with pytest.raises(mf.ManifestError, match="cannot be read"):
        mf.manifest_rows(tmp_path)
