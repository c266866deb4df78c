"""Atomic file output: write to a unique temporary file beside the target, then rename.

Readers never see a half-written file (a crash leaves the old file or none, plus at most a
hidden ``.<name>.*.tmp<suffix>`` file), and two processes writing the same target never
share a temporary name: each writer gets its own from :func:`tempfile.mkstemp`, and the
last :func:`os.replace` wins with a complete file.

    with atomic_path("results/run.png") as tmp:   # tmp keeps the suffix: ".png"
        fig.savefig(tmp)
    atomic_write_text("results/run.json", json.dumps(report))

A target that exists and is not a regular file (a device such as ``/dev/null``, a FIFO, a
directory) is refused with an ``OSError`` before anything is written; a symbolic link is
written through (the file it points to is replaced, the link stays).

Errors are ``OSError`` subclasses whose ``filename`` is the *target* path, so a caller's
one-line message names the file the user asked for, not the temporary one.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from pathlib import Path
from typing import Iterator

# The process umask, read once: mkstemp creates 0600 files, renamed outputs get the mode
# a plain open() would have given them.
_UMASK = os.umask(0)
os.umask(_UMASK)


def _named(exc: OSError, path: Path) -> OSError:
    """The same kind of error, naming the target file."""
    return type(exc)(exc.errno, exc.strerror or str(exc), str(path))


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, mkdir: bool = True) -> Iterator[Path]:
    """Yield a fresh temporary path in ``path``'s directory; on success rename it to ``path``.

    The temporary name ends with ``path``'s suffix (a symlink's own, not its target's), so writers
    that infer the format from the extension (matplotlib) behave as for ``path``. On an exception the temporary file
    is removed and the target is left untouched. ``mkdir`` creates missing parent directories.
    """
    path = Path(path)
    suffix = path.suffix             # the name given says the format, also when it is a link's
    if path.is_symlink():            # write through a link: the file it names is replaced, the link stays
        path = path.resolve()
    if path.exists() and not path.is_file():
        # a device, FIFO or socket (or a directory) must never be renamed over
        raise OSError(errno.EINVAL, "not a regular file", str(path))
    try:
        if mkdir:
            path.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=f".tmp{suffix}")
    except OSError as exc:
        raise _named(exc, path) from None
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_UMASK)
        with open(tmp, "rb") as f:   # flush the data before the rename makes it visible
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if exc.filename in (None, name, str(tmp)):
            raise _named(exc, path) from None
        raise
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically; returns ``path``."""
    return atomic_write_bytes(path, text.encode(encoding))
