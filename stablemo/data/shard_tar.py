"""A shard's tar file, built in memory: POSIX ustar headers with fixed owner, mode and time.

`stablemo data shard` writes every shard through `tar_bytes`. Python's `tarfile` (which
WebDataset's TarWriter drives) costs ~0.3 ms per clip here: a TarInfo copy, a pax check and a
BytesIO round trip per member, about a third of a shard's whole writing time. A shard needs none
of that: every member is a regular file with a short ASCII name, so each header is one fixed
512-byte block in which only the name, the size and the checksum change.

The bytes are those WebDataset 1.0.2's `TarWriter(encoder=False, mtime=0, user=group="stablemo",
mode=0o444)` writes under Python 3.11 (tests/test_shards.py compares them), so shards written
before and after this writer are the same files; unlike tarfile's, they do not depend on the
Python version (3.12 writes other device fields). Readers are unchanged (WebDataset's
`tar_file_expander`, any `tar`).
"""

from __future__ import annotations

from collections.abc import Iterable

BLOCK = 512
RECORD = 20 * BLOCK  # tar's blocking factor: the archive ends on a whole record, as tarfile pads it
OWNER = b"stablemo"
MODE = 0o444  # read-only for everyone: a shard is never edited in place
MAX_SIZE = 8**11 - 1  # the largest size 11 octal digits hold (8 GiB); shards stay far below


def _field(text: bytes, width: int) -> bytes:
    return text + b"\0" * (width - len(text))


def _octal(value: int, width: int) -> bytes:
    """`width - 1` octal digits and a NUL: the numeric field form tar readers expect."""
    return b"%0*o\0" % (width - 1, value)


# the header's fields after the name (100 bytes) and before the checksum (148..156), without the
# size (124..136), which changes per member; see POSIX.1 "ustar Interchange Format"
_MODE_IDS = _octal(MODE, 8) + _octal(0, 8) + _octal(0, 8)  # mode, uid, gid
_MTIME = _octal(0, 12)
_TAIL = (b"0"  # typeflag: a regular file
         + _field(b"", 100)  # linkname
         + b"ustar\x0000"  # magic and version
         + _field(OWNER, 32) + _field(OWNER, 32)  # uname, gname
         + _field(b"", 8) + _field(b"", 8)  # devmajor, devminor: empty for a regular file
         + _field(b"", 155) + _field(b"", 12))  # prefix, padding to 512
_FIXED_SUM = sum(b" " * 8) + sum(_TAIL)  # the checksum counts its own field as 8 spaces


def header(name: str, size: int) -> bytes:
    """The 512-byte ustar header of a regular file `name` of `size` bytes."""
    raw = name.encode("ascii")  # shard member names are keys and extensions: ASCII by construction
    if not 0 < len(raw) <= 100 or b"\0" in raw:
        raise ValueError(f"tar member name {name!r}: must be 1-100 ASCII characters")
    if not 0 <= size <= MAX_SIZE:
        raise ValueError(f"tar member {name!r}: {size} bytes, more than a ustar header holds")
    head = _field(raw, 100) + _MODE_IDS + _octal(size, 12) + _MTIME
    checksum = sum(head) + _FIXED_SUM
    block = head + b"%06o\0 " % checksum + _TAIL
    assert len(block) == BLOCK
    return block


def tar_bytes(members: Iterable[tuple[str, bytes]]) -> bytes:
    """A whole tar archive of `(name, data)` members, in the order given."""
    parts, offset = [], 0
    for name, data in members:
        parts.append(header(name, len(data)))
        parts.append(data)
        pad = -len(data) % BLOCK
        parts.append(b"\0" * pad)
        offset += BLOCK + len(data) + pad
    offset += 2 * BLOCK  # two zero blocks end the archive
    end = 2 * BLOCK + (-offset % RECORD)
    parts.append(b"\0" * end)
    return b"".join(parts)
