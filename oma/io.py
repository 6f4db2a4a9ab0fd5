"""Writing files without ever leaving a half-written one behind (cli.md).

Every robomill writer goes through :func:`atomic_write`: the output is built under a temporary name
in the destination's own directory (so the final rename stays on one file system and is atomic) and
only renamed into place when writing succeeded. If writing fails, the temporary output is removed
and whatever was at the destination before is left untouched.
"""

from __future__ import annotations

import os
import secrets
import shutil
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_write"]


@contextmanager
def atomic_write(path, *, directory: bool = False, last: Sequence[str] = ()) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it to ``path`` when the block succeeds.

    Parameters
    ----------
    path : str or path-like
        The final file (or directory) to produce. Missing parent directories are created.
    directory : bool, optional
        ``False`` (default): the yielded path is a fresh empty file the caller overwrites (by
        name, so libraries that want a file name can write it); on success it replaces ``path``
        with ``os.replace`` (atomic on POSIX and Windows). ``True``: the yielded path is an empty
        temporary directory the caller fills. On success, if ``path`` does not exist the whole
        directory is renamed into place (atomic); if ``path`` is an existing directory, each
        top-level entry of the new directory replaces the entry of the same name there (each
        replacement atomic), so files the writer did not produce (e.g. a ``reference_frf.csv``
        kept beside a record) survive.
    last : sequence of str, optional
        With ``directory=True``: names of entries to install after all others (the index file,
        e.g. ``record.yaml``, so that it never names data that is not in place yet).

    Yields
    ------
    pathlib.Path
        The temporary file or directory to write.

    Raises
    ------
    NotADirectoryError
        ``directory=True`` and ``path`` exists but is not a directory.
    IsADirectoryError
        ``directory=False`` and ``path`` is an existing directory.

    Notes
    -----
    On any exception inside the block (including ``KeyboardInterrupt``) the temporary output is
    removed and the exception propagates.
    """
    target = Path(os.fspath(path))
    parent = target.parent
    parent.mkdir(parents=True, exist_ok=True)  # like `mkdir -p`: `-o out/new/model.yaml` works
    if directory:
        if target.exists() and not target.is_dir():
            raise NotADirectoryError(f"{target}: exists and is not a directory")
        tmp = _fresh(parent, f".{target.name}.", ".tmp", directory=True)
        try:
            yield tmp
            _install_directory(tmp, target, last)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return

    if target.is_dir():
        raise IsADirectoryError(f"{target}: is a directory, expected a file name")
    # Keep the suffix last so libraries that look at the extension (pyuff) see the real one.
    tmp = _fresh(parent, f".{target.stem}.", f".tmp{target.suffix}", directory=False)
    try:
        yield tmp
        os.replace(tmp, target)
    except BaseException:
        try:
            tmp.unlink()
        except FileNotFoundError:
            pass
        raise


def _fresh(parent: Path, prefix: str, suffix: str, *, directory: bool) -> Path:
    """Create a new empty file or directory with a random name; permissions follow the umask
    (unlike ``tempfile``, whose 0600/0700 would end up on the user's output)."""
    for _ in range(100):
        tmp = parent / f"{prefix}{secrets.token_hex(4)}{suffix}"
        try:
            if directory:
                os.mkdir(tmp, 0o777)
            else:
                os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
            return tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"{parent}: could not create a temporary name for {prefix}*{suffix}")


def _install_directory(tmp: Path, target: Path, last: Sequence[str]) -> None:
    """Move a finished temporary directory into place (see :func:`atomic_write`)."""
    if not target.exists():
        try:
            os.rename(tmp, target)
            return
        except OSError:
            if not target.is_dir():  # something else appeared there meanwhile
                raise
            # another process created the directory meanwhile: merge below
    for entry in sorted(tmp.iterdir(), key=lambda e: (e.name in last, e.name)):
        dest = target / entry.name
        if entry.is_dir() and dest.is_dir():
            shutil.rmtree(dest)
        os.replace(entry, dest)
    tmp.rmdir()
