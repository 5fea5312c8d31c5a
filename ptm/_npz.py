"""Reading the named arrays of an ``.npz`` file without trusting the sizes it declares.

Each ``.npy`` member opens with a header declaring its shape and dtype, and numpy allocates
``prod(shape) * itemsize`` bytes before it reads any data: a forged header (a 745 GiB shape in a 2 kB
file) would end in a ``MemoryError``. Here every declared size is checked first against what the zip
member can hold: its uncompressed size in the zip directory, and no more than its compressed bytes
(themselves no more than the file) can expand to, 1:1 stored and at most 1032:1 deflated, the deflate
format's limit. ``np.savez`` stores, ``np.savez_compressed`` deflates; other methods are refused.

    >>> import tempfile
    >>> path = Path(tempfile.mkdtemp()) / "run.npz"; np.savez(path, labels=np.arange(3))
    >>> read_npz(path, "dataset")
    {'labels': array([0, 1, 2])}
"""

from __future__ import annotations

import math
import zipfile
import zlib
from pathlib import Path

import numpy as np
from numpy.lib import format as npy

__all__ = ["read_npz"]

# What one compressed byte can become: deflate emits at most a 258-byte match per 2 bits (zlib's technical notes).
_EXPANSION = {zipfile.ZIP_STORED: 1, zipfile.ZIP_DEFLATED: 1032}
# Format 3.0 differs from 2.0 only in the header's text encoding (utf-8 for non-latin-1 field names); its shape
# and item size read the same through the 2.0 reader.
_HEADER_READERS = {(1, 0): npy.read_array_header_1_0, (2, 0): npy.read_array_header_2_0,
                   (3, 0): npy.read_array_header_2_0}


def read_npz(path: Path, kind: str) -> dict[str, np.ndarray]:
    """The arrays of the ``.npz`` file at ``path``, by name (as ``np.load`` gives them); a ``ValueError`` naming it
    (a ``kind`` file) and, for a size its member cannot hold, the member, when it is truncated, foreign, damaged or
    forged."""
    try:
        with open(path, "rb") as handle:
            if handle.read(len(npy.MAGIC_PREFIX)) == npy.MAGIC_PREFIX:
                raise ValueError(f"it holds a single array (.npy), not the named arrays of a {kind} (.npz)")
        file_size = path.stat().st_size
        with zipfile.ZipFile(path) as archive:
            return {info.filename.removesuffix(".npy"): _read_member(archive, info, file_size)
                    for info in archive.infolist()}
    except (OSError, ValueError, EOFError, KeyError, NotImplementedError, zipfile.BadZipFile, zlib.error) as error:
        # a truncated, foreign or damaged file: BadZipFile, zlib.error, EOFError or NotImplementedError from deep
        # inside zipfile and numpy
        raise ValueError(f"{path} is not a readable {kind} file ({type(error).__name__}: {error})") from None


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, file_size: int) -> np.ndarray | bytes:
    """The array in member ``info`` (its bytes, as numpy gives them, if it is no ``.npy``), read only once the
    size its header declares is known to fit in the member; else a ``ValueError`` naming the member."""
    if info.flag_bits & 0x1:
        raise ValueError(f"member {info.filename!r} is encrypted")
    expansion = _EXPANSION.get(info.compress_type)
    if expansion is None:
        raise ValueError(f"member {info.filename!r} uses zip compression method {info.compress_type}; "
                         "an .npz member is stored (0) or deflated (8)")
    holds = min(info.file_size, expansion * min(info.compress_size, file_size))
    with archive.open(info) as member:
        is_array = member.read(len(npy.MAGIC_PREFIX)) == npy.MAGIC_PREFIX
        member.seek(0)
        if not is_array:
            return member.read()  # no more than the member's compressed bytes expand to
        version = npy.read_magic(member)
        reader = _HEADER_READERS.get(version)
        if reader is None:
            raise ValueError(f"member {info.filename!r} has .npy format version {version}, not 1.0, 2.0 or 3.0")
        shape, _, dtype = reader(member)
        if any(not 0 <= side <= np.iinfo(np.intp).max for side in shape):
            raise ValueError(f"member {info.filename!r} declares shape {shape}, with a side outside [0, 2**63)")
        # a zero-byte item counts as one: a billion of them fit in no bytes, and a float cast would take 8 GB
        declared = math.prod(shape) * max(dtype.itemsize, 1)
        if member.tell() + declared > holds:
            raise ValueError(f"member {info.filename!r} declares a {dtype} array of shape {shape} "
                             f"({declared:,} bytes), more than its {holds:,} bytes can hold")
        member.seek(0)
        return npy.read_array(member, allow_pickle=False)
