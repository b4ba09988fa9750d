"""Gmsh files bounded before meshio reads them: MSH 4.1, 4.0 and 2.2, ASCII or binary, walked
section by section in meshio 5.3's reading order; every count meshio allocates from (each entity
block's nodes and elements, $Entities, $Periodic, $NodeData/$ElementData) bounded by its section's
total and the bytes left, the largest node tag (which sizes meshio's tag table) in the memory
estimate. Used by :func:`glsim.io.meshfiles.check_mesh_file`."""
from __future__ import annotations

import contextlib
import mmap
import re
import struct
from pathlib import Path

import numpy as np

from glsim.errors import SceneError
from glsim.limits import check_mesh_memory


# Gmsh: the fewest bytes a node or an element takes in the file (ASCII: "1 0 0 0\n"; binary: a
# 4-byte tag and 3 doubles; an element's tag and one node), which bounds what a header may declare
_GMSH_MIN_BYTES = {False: (8, 4), True: (28, 8)}
_GMSH_FIX = "write or export the file again (damaged or truncated?)"


def _section(mm, name: bytes) -> int:
    """Where the data after the line ``name`` (e.g. b"$Nodes") starts in the mapped file; -1: none."""
    found = re.search(rb"(?:^|\n)" + re.escape(name) + rb"\r?\n", mm)
    return found.end() if found else -1


def _gmsh_header(mm, name: bytes, version: str, binary: bool, data_size: int) -> tuple[int, int, int]:
    """(entity blocks, entries, largest tag) a Gmsh section header declares (MSH 2: blocks 1, tag 0)."""
    at = _section(mm, name)
    if at < 0:
        return 0, 0, 0
    wide = 2 if version == "4.0" else 4                 # MSH 4.0 declares no tags in the header
    if version.startswith("4") and binary:
        fields = struct.unpack_from(f"<{wide}{'Q' if data_size == 8 or version == '4.0' else 'I'}", mm, at)
    else:
        mm.seek(at)
        fields = [int(x) for x in mm.readline().split()[:wide]]
    if not version.startswith("4"):
        return 1, fields[0], 0
    return fields[0], fields[1], fields[3] if wide == 4 else 0


def _gmsh_format(mm) -> tuple[str, bool, int, int]:
    """(version, binary, data size, where the sections start) of a Gmsh file, read as meshio reads
    it ($Comments before $MeshFormat skipped); _Unread where it is no Gmsh file meshio reads."""
    g = _Gmsh("", mm, False)
    line = g.line().strip()
    while line == b"$Comments":
        g.to_end(b"Comments")
        line = g.line().strip()
    if line != b"$MeshFormat":
        raise _Unread
    try:
        version, binary, data_size = g.line().split()[:3]
        version, binary, data_size = version.decode(), binary == b"1", int(data_size)
    except (ValueError, UnicodeDecodeError):
        raise _Unread from None
    g.pos += 4 * binary                                  # the binary file's int 1 (its byte order)
    g.to_end(b"MeshFormat")
    return version, binary, data_size, g.pos


def check_gmsh(path: Path) -> None:
    """Gmsh's declared node and element counts (and MSH 4.1's largest node tag, which sizes meshio's
    tag table) against the file's length and the memory estimate, before meshio allocates them; the
    file is then walked section by section as meshio reads it (:class:`_Gmsh`), each block's count
    bounded before meshio allocates from it."""
    size = path.stat().st_size
    if size == 0:
        return
    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        try:
            version, binary, data_size, start = _gmsh_format(mm)
        except _Unread:
            return                                       # meshio names it
        try:                                             # the headers found first (the walk below reads them in order)
            nodes = _gmsh_header(mm, b"$Nodes", version, binary, data_size)
            elements = _gmsh_header(mm, b"$Elements", version, binary, data_size)
        except (ValueError, IndexError, struct.error):
            nodes = elements = (0, 0, 0)
        for name, (blocks, n, _), least in zip(("$Nodes", "$Elements"), (nodes, elements), _GMSH_MIN_BYTES[binary]):
            if min(n, blocks) < 0 or max(n, blocks) * least > size:
                raise SceneError(str(path), f"its {name} section declares {n:,} entries in {blocks:,} blocks, more "
                                 f"than its {size:,} bytes can hold (at least {least} bytes each)", _GMSH_FIX)
        check_mesh_memory(str(path), nodes[1], elements[1], 16 * max(nodes[2], 0), " (its $Nodes and $Elements)")
        major = version.split(".")[0]
        if major in ("2", "4") and (not binary or data_size in (4, 8)):
            g = _Gmsh(str(path), mm, binary, version if major == "4" else "2", data_size, start)
            with contextlib.suppress(_Unread):
                g.walk()
            check_mesh_memory(str(path), g.nodes, g.elements, 16 * g.max_tag + g.data_bytes,
                              " (its $Nodes and $Elements blocks)")


class _Unread(Exception):
    """Where meshio's Gmsh reader fails before it allocates more: the rest is left to meshio."""


_WS = b" \t\n\r\v\f"
_SPACE = np.zeros(256, bool)
_SPACE[list(_WS)] = True
_TOKEN = re.compile(rb"[ \t\n\r\v\f]*([^ \t\n\r\v\f]{1,64})[ \t\n\r\v\f]*")
_BLANKS = re.compile(rb"[ \t\n\r\v\f]*")
_INTEGER = re.compile(rb"[+-]?\d{1,40}")
_TOKEN_CHUNK = 1 << 24


def _skip_tokens(mm, pos: int, k: int) -> int:
    """Where the (k+1)-th whitespace-separated token from ``pos`` (at a token) starts, read in chunks
    of the mapped file; -1 where the file has fewer than k."""
    size = len(mm)
    while k > 0:
        if pos >= size:
            return -1
        n = min(_TOKEN_CHUNK, size - pos)
        space = _SPACE[np.frombuffer(mm, np.uint8, n, pos)]
        last = pos + n == size
        if last:
            space = np.append(space, True)
        ends = np.flatnonzero(~space[:-1] & space[1:])            # a token's last byte
        if len(ends) >= k:
            pos += int(ends[k - 1]) + 1
            break
        if last:
            return -1
        k -= len(ends)
        pos += n - 1
    return _BLANKS.match(mm, pos).end()


def _tag_range(mm, at: int, n: int, record, every: int = 1) -> tuple[float, float]:
    """(largest, smallest) of n node tags at ``at`` in the mapped file: binary values (``record``, a
    dtype: the tag or a record with a field 'tag'), or ASCII tokens up to ``record`` (an offset; every
    ``every``-th token a tag). The views on the map end here, so that it closes whatever is raised next."""
    if n == 0:
        return 0.0, 1.0
    if isinstance(record, np.dtype):
        tags = np.frombuffer(mm, record, n, at)
        tags = tags["tag"] if record.names else tags
    else:
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tags = np.fromstring(mm[at:record], dtype=np.float64, sep=" ")[::every]   # MSH 2: 'tag x y z'
    return (float(tags.max()), float(tags.min())) if len(tags) else (0.0, 1.0)


class _Gmsh:
    """A cursor over a mapped Gmsh file that reads what meshio 5.3's reader reads, in its order and
    its way (ASCII: whitespace-separated tokens, as numpy's fromfile reads them, each followed by its
    whitespace; binary: packed values), so that every count meshio allocates from — each $Nodes and
    $Elements entity block's, $Entities', $Periodic's, $NodeData's — is bounded before meshio sees it:
    against its section's total, the bytes left in the file and (with the largest node tag, which
    sizes meshio's tag table) the memory estimate. Where meshio fails before allocating more (an
    unknown element type, the end of the file) it raises _Unread."""

    def __init__(self, path: str, mm, binary: bool, version: str = "4.1", data_size: int = 8, pos: int = 0):
        self.path, self.mm, self.binary, self.pos = path, mm, binary, pos
        self.v40 = version == "4.0"                      # MSH 4.0: counts are C longs, element nodes C ints
        self.v2 = version == "2"                         # MSH 2: a count line, then the nodes or elements
        self.size_t = "Q" if self.v40 or data_size == 8 else "I"
        self.nodes = self.elements = self.max_tag = self.data_bytes = 0

    # ---- reading as meshio reads
    def left(self) -> int:
        return len(self.mm) - self.pos

    def line(self) -> bytes:
        self.mm.seek(self.pos)
        line = self.mm.readline()
        self.pos = self.mm.tell()
        return line

    def to_end(self, name: bytes) -> None:
        """Past the line $End<name> (meshio's fast-forward; the end of the file if none)."""
        while self.left() > 0 and self.line().strip() != b"$End" + name:
            pass

    def ints(self, fmt: str, what: str) -> tuple:
        """The integers of struct format ``fmt`` (binary), or as many tokens (ASCII; refused unless integers)."""
        if self.binary:
            try:
                values = struct.unpack_from("<" + fmt, self.mm, self.pos)
            except struct.error:
                raise _Unread from None
            self.pos += struct.calcsize("<" + fmt)
            return values
        values = []
        for _ in fmt:
            m = _TOKEN.match(self.mm, self.pos)
            if m is None:
                raise _Unread
            if not _INTEGER.fullmatch(m.group(1)) or (m.end() == m.end(1) and m.end() < len(self.mm)):
                raise SceneError(self.path, f"{what} holds {m.group(1)[:40].decode(errors='replace')!r} where an "
                                 "integer goes", _GMSH_FIX)
            values.append(int(m.group(1)))
            self.pos = m.end()
        return tuple(values)

    def count(self, fmt: str, what: str, most: int | None = None, of: str = "") -> int:
        """One count (struct format ``fmt``), refused if negative or above ``most`` (what its section has left)."""
        (n,) = self.ints(fmt, what)
        if n < 0 or (most is not None and n > most):
            raise SceneError(self.path, f"{what} declares {n:,} {of}, " + (
                "a negative count" if n < 0 else f"more than the {most:,} its section declares"), _GMSH_FIX)
        return n

    def skip(self, n: int, item: int, what: str, declared: str = "") -> int:
        """Past ``n`` values of ``item`` bytes each (binary) or ``n`` tokens (ASCII: at least 2 bytes each
        with its separator), refused where the bytes left cannot hold them (``declared``: what the file
        declares, for the message). Returns where they start."""
        self.fits(n, item, what, declared or f"{n:,} values")
        at = self.pos
        if self.binary:
            self.pos += n * item
        elif n:
            self.pos = _skip_tokens(self.mm, self.pos, n)
            if self.pos < 0:
                raise _Unread
        return at

    def fits(self, n: int, item: int, what: str, declared: str) -> None:
        """SceneError naming ``what`` unless the bytes left can hold n values of ``item`` bytes (binary)
        or n tokens (ASCII)."""
        least = item if self.binary else 2
        if n * least > self.left() + (0 if self.binary else 1):
            raise SceneError(self.path, f"{what} declares {declared}, more than the {self.left():,} bytes left in the "
                             "file can hold", _GMSH_FIX)

    def section_fits(self, blocks: int, total: int, item: int, tokens: int, what: str, of: str) -> None:
        """A section header's blocks (each at least 3 ints and a count) and ``total`` entries (each at
        least ``item`` bytes, or ``tokens`` tokens) against the bytes left, before meshio sizes its arrays."""
        header = 12 + struct.calcsize(self.size_t)
        if min(blocks, total) < 0 or (blocks * header + total * item if self.binary
                                      else 2 * (4 * blocks + tokens * total) - 1) > self.left():
            raise SceneError(self.path, f"{what} declares {total:,} {of} in {blocks:,} blocks, more than the "
                             f"{self.left():,} bytes left in the file can hold", _GMSH_FIX)

    # ---- the sections
    def walk(self) -> None:
        sections = {b"Entities": self.entities, b"Nodes": self.node_blocks, b"Elements": self.element_blocks,
                    b"Periodic": self.periodic, b"NodeData": self.data, b"ElementData": self.data}
        if self.v2:                                      # (its $Periodic is read line by line)
            sections = {b"Nodes": self.nodes_v2, b"Elements": self.elements_v2, b"NodeData": self.data,
                        b"ElementData": self.data}
        while self.left() > 0:
            line = self.line().strip()
            if not line:
                continue
            if not line.startswith(b"$"):
                raise _Unread
            name = line[1:].strip()
            if name in sections:
                sections[name](f"its ${name.decode()} section")
            self.to_end(name)

    def entities(self, what: str) -> None:
        numbers = self.ints(self.size_t * 4, what)
        least = 28 + struct.calcsize(self.size_t) if self.binary else 10   # a tag, 3 doubles, a count of tags
        if min(numbers) < 0 or sum(numbers) * least > self.left():
            raise SceneError(self.path, f"{what} declares {', '.join(f'{n:,}' for n in numbers)} entities, more "
                             f"than the {self.left():,} bytes left in the file can hold", _GMSH_FIX)
        for d, n in enumerate(numbers):
            for k in range(n):
                name = f"{what}: entity {k + 1} of dimension {d}"
                self.ints("i", name)
                self.skip(6 if self.v40 or d else 3, 8, name)
                for of in ("physical tags", "bounding entities")[:1 + (d > 0)]:
                    self.skip(self.count(self.size_t, name, of=of), 4, f"{name}'s {of}")

    def node_blocks(self, what: str) -> None:
        if self.v40 and not self.binary:
            blocks, total = self._line_ints(2, what)
        else:
            blocks, total, *_ = self.ints(self.size_t * (2 if self.v40 else 4), what)
        per_node = 28 if self.v40 else struct.calcsize(self.size_t) + 24      # a tag and 3 doubles
        self.section_fits(blocks, total, per_node, 4, what, "nodes")
        self.nodes += total
        seen = 0
        for k in range(blocks):
            name = f"{what}: entity block {k + 1}"
            if self.v40 and not self.binary:
                *_, n = self._line_ints(4, name)
                self._check_count(n, total - seen, name, "nodes")
                self._ascii_v40_nodes(n, name)
            else:
                *_, parametric = self.ints("iii", name)
                if parametric and not self.v40:
                    raise _Unread                        # meshio: parametric nodes not implemented
                n = self.count(self.size_t, name, total - seen, "nodes")
                self.fits(n if self.binary else 4 * n, per_node, name, f"{n:,} nodes")
                self._tags(n, name)
            seen += n

    def _tags(self, n: int, name: str) -> None:
        """Past a block's n node tags and coordinates, the largest tag kept (refused below 1)."""
        if self.v40:                                     # binary records: an int tag, 3 doubles
            tags = _tag_range(self.mm, self.skip(n, 28, name), n, np.dtype([("tag", "<i4"), ("x", "<f8", 3)]))
        else:
            item = struct.calcsize(self.size_t)
            at = self.skip(n, item, name)
            tags = _tag_range(self.mm, at, n, np.dtype(f"<u{item}") if self.binary else self.pos)
            self.skip(3 * n, 8, f"{name}'s coordinates")
        if n:
            self._keep_tag(*tags, name)

    def _keep_tag(self, most: float, least: float, name: str) -> None:
        if least < 1:
            raise SceneError(self.path, f"{name} holds node tag {least:.0f}", "number nodes from 1; " + _GMSH_FIX)
        if most > 2 ** 53:
            raise SceneError(self.path, f"{name} holds node tag {most:.6g}, more than any mesh has",
                             "number the nodes 1, 2, … (renumber them in Gmsh)")
        self.max_tag = max(self.max_tag, int(most))
        check_mesh_memory(self.path, self.nodes, self.elements, 16 * self.max_tag,
                          f" (its $Nodes, with node tags up to {int(most):,} in {name.split(': ')[-1]})")

    def _line_ints(self, n: int, what: str) -> list[int]:
        """MSH 4.0 ASCII's node headers: a line of integers, read as meshio reads it (int of each field)."""
        try:
            values = [int(x) for x in self.line().split()]
        except ValueError:
            raise _Unread from None
        if len(values) != n:
            raise _Unread
        return values

    def _check_count(self, n: int, most: int, name: str, of: str) -> None:
        if n < 0 or n > most:
            raise SceneError(self.path, f"{name} declares {n:,} {of}, " + (
                "a negative count" if n < 0 else f"more than the {most:,} its section declares"), _GMSH_FIX)

    def _ascii_v40_nodes(self, n: int, name: str) -> None:
        """MSH 4.0 ASCII: a line 'tag x y z' per node, read line by line (as meshio does)."""
        if n * 8 > self.left():
            raise SceneError(self.path, f"{name} declares {n:,} nodes, more than the {self.left():,} bytes left in "
                             "the file can hold (at least 8 bytes each)", _GMSH_FIX)
        most, least = 0, 1
        for _ in range(n):
            try:
                tag = int(self.line().split()[0])
            except (ValueError, IndexError):
                raise _Unread from None
            most, least = max(most, tag), min(least, tag)
        if n:
            self._keep_tag(most, least, name)

    def nodes_v2(self, what: str) -> None:
        """MSH 2: a count line, then 'tag x y z' values (ASCII; meshio sizes its tag table by the largest
        tag) or records of an int tag and 3 doubles (binary; meshio requires tags 1…n)."""
        (total,) = self._line_ints(1, what)
        self._check_count(total, total, what, "nodes")
        self.nodes += total
        self.fits(total if self.binary else 4 * total, 28, what, f"{total:,} nodes")
        if self.binary:
            return
        at = self.pos
        self.skip(4 * total, 8, what)
        if total:
            most, least = _tag_range(self.mm, at, total, self.pos, every=4)
            self._keep_tag(most, least, what)

    def elements_v2(self, what: str) -> None:
        """MSH 2: a count line, then lines (ASCII: meshio reads them one by one, allocating as it goes) or
        binary blocks of an element type, a count and a number of tags, each bounded here."""
        from meshio._common import num_nodes_per_cell
        from meshio.gmsh.common import _gmsh_to_meshio_type

        (total,) = self._line_ints(1, what)
        self._check_count(total, total, what, "elements")
        self.fits(2 * total, 4 if self.binary else 2, what, f"{total:,} elements")
        self.elements += total
        seen, k = 0, 0
        while self.binary and seen < total:
            k += 1
            name = f"{what}: element block {k}"
            kind, n, tags = self.ints("iii", name)
            self._check_count(tags, max(tags, 0), name, "tags")
            self._check_count(n, total - seen, name, "elements")
            nodes = num_nodes_per_cell.get(_gmsh_to_meshio_type.get(kind, ""))
            if nodes is None:
                raise _Unread                            # meshio: no such element type
            self.skip(n * (1 + tags + nodes), 4, name, f"{n:,} elements of {nodes} nodes and {tags:,} tags")
            seen += n

    def element_blocks(self, what: str) -> None:
        from meshio._common import num_nodes_per_cell
        from meshio.gmsh.common import _gmsh_to_meshio_type

        blocks, total, *_ = self.ints(self.size_t * (2 if self.v40 else 4), what)
        value = 4 if self.v40 else struct.calcsize(self.size_t)
        self.section_fits(blocks, total, 2 * value, 2, what, "elements")       # a tag and a node each
        self.elements += total
        seen = 0
        for k in range(blocks):
            name = f"{what}: entity block {k + 1}"
            *_, kind = self.ints("iii", name)
            n = self.count(self.size_t, name, total - seen, "elements")
            self.fits(2 * n, value, name, f"{n:,} elements")     # a tag and a node each, before the type
            nodes = num_nodes_per_cell.get(_gmsh_to_meshio_type.get(kind, ""))
            if nodes is None:
                raise _Unread                            # meshio: no such element type
            self.skip(n * (1 + nodes), value, name, f"{n:,} elements of {nodes} nodes")
            seen += n

    def periodic(self, what: str) -> None:
        if self.v40:                                     # its links mix lines and values: bounded link by link
            n = self.count("i", what, self.left(), "periodic links")
            for k in range(n):
                name = f"{what}: link {k + 1}"
                self.ints("iii", name)
                if self.binary:
                    (m,) = self.ints("q", name)
                    if m < 0:
                        self.skip(16, 8, name)
                        m = self.count("Q", name, of="node pairs")
                else:
                    line = self.line().strip()
                    if line.startswith(b"Affine"):
                        line = self.line()
                    try:
                        m = int(line)
                    except ValueError:
                        raise _Unread from None
                    self._check_count(m, self.left(), name, "node pairs")
                self.skip(2 * m, 4, f"{name}'s node pairs")
            return
        n = self.count(self.size_t, what, self.left(), "periodic links")
        for k in range(n):
            name = f"{what}: link {k + 1}"
            self.ints("iii", name)
            self.skip(self.count(self.size_t, name, self.left(), "affine values"), 8, name)
            self.skip(2 * self.count(self.size_t, name, self.left(), "node pairs"), struct.calcsize(self.size_t),
                      f"{name}'s node pairs")

    def data(self, what: str) -> None:
        """$NodeData / $ElementData (meshio's _read_data): line counts of string, real and integer tags,
        then the values; their decoded bytes go into the memory estimate."""
        integers = []
        for kind in ("string", "real", "integer"):
            try:
                n = int(self.line().decode())
            except (ValueError, UnicodeDecodeError):
                raise _Unread from None
            self._check_count(n, self.left(), what, f"{kind} tags")
            lines = [self.line() for _ in range(n)]
            if kind == "integer":
                try:
                    integers = [int(x.decode()) for x in lines]
                except (ValueError, UnicodeDecodeError):
                    raise _Unread from None
        if len(integers) < 3:
            raise _Unread
        components, items = integers[1], integers[2]
        self._check_count(min(components, items), items, what, "components or items")
        if self.binary:
            self.skip(items, 4 + 8 * components, f"{what}'s {items:,} items")
        else:
            self.skip(items * (1 + components), 8, f"{what}'s {items:,} items")
        self.data_bytes += 8 * items * (1 + components)
