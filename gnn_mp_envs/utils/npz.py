"""Byte-reproducible, atomically written ``.npz`` caches and a loader that names damaged files.

Every dataset cache of the project (critical samples, tree-sampler examples) goes through
:func:`write_npz` / :func:`read_npz`: arrays are stored without pickles and with fixed zip
timestamps, so the same content gives the same bytes; the file appears under its name only
when complete (:func:`gnn_mp_envs.utils.io.atomic_path`); and a file that cannot be used
(empty, truncated, CRC errors, not an npz, missing arrays, another format version) raises
:class:`DatasetCacheError` with one line naming it, so callers can regenerate.
"""

from __future__ import annotations

import io
import pickle
import zipfile
import zlib
from pathlib import Path
from typing import Mapping

import numpy as np

from gnn_mp_envs.utils.io import atomic_path


class DatasetCacheError(ValueError):
    """A dataset file that cannot be used; the message is one line naming the file."""


#: What numpy / zipfile raise on a damaged npz.
DAMAGED = (zipfile.BadZipFile, zlib.error, EOFError, ValueError, KeyError, TypeError, IndexError,
           AttributeError, pickle.UnpicklingError, UnicodeDecodeError, OverflowError)


def write_npz(path: str | Path, arrays: Mapping[str, np.ndarray]) -> Path:
    """Write ``arrays`` as a deflated npz whose bytes depend only on the arrays."""
    with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, arr in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asarray(arr), allow_pickle=False)
            info = zipfile.ZipInfo(name + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(info, buf.getvalue())
    return Path(path)


def read_npz(path: str | Path, format_version: int) -> dict[str, np.ndarray]:
    """All arrays of an npz written by :func:`write_npz` with a ``format_version`` entry.

    Raises :class:`DatasetCacheError` for another format version or a damaged file and
    ``FileNotFoundError`` for a missing one.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {name: z[name] for name in z.files}
        version = int(arrays["format_version"])
    except DAMAGED as exc:
        lines = str(exc).strip().splitlines()
        detail = f"{type(exc).__name__}: {lines[0][:100]}" if lines else type(exc).__name__
        raise DatasetCacheError(f"{path}: unreadable dataset file ({detail})") from None
    if version != format_version:
        raise DatasetCacheError(f"{path}: format version {version}, expected {format_version}")
    return arrays
