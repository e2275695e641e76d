"""
A recording's files: errors named by file, outputs that never overwrite an input, atomic writes.

:class:`BagError` is what every reader and writer of a recording raises (one line: the file and
the problem); :func:`check_output` refuses, before any work, an output that is an input, exists
(without ``force``) or cannot be created; :func:`write_atomic` and the writer's ``.part``
(:func:`partial_path`) never leave a half-written file under the final name.
"""
from __future__ import annotations

import contextlib
import os
from pathlib import Path
import tempfile
from typing import Iterable


class BagError(Exception):
    """A recording cannot be read or written; the message names the file and the problem."""

    def __init__(self, path, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f'{path}: {problem}')


def _same_file(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return os.path.realpath(a) == os.path.realpath(b)


def check_output(out, inputs: Iterable = (), force: bool = False, what: str = 'output') -> Path:
    """
    Refuse an output that is one of the inputs or that exists.

    Refuse an output that is one of ``inputs`` (same real path or inode; even with ``force``) or
    that exists (without ``force``). :class:`FileExistsError`, one line.
    """
    o = Path(out)
    for i in inputs:
        if i is not None and _same_file(o, Path(i)):
            raise FileExistsError(f'{o}: the {what} is also an input '
                                  f'({i}); refusing to write over '
                                  'it (even with --force); choose another file')
    if o.is_dir():
        raise FileExistsError(f'{o}: the {what} is a directory, not a file')
    if o.exists() and not force:
        raise FileExistsError(f'{o}: the {what} exists; refusing to overwrite it '
                              '(pass --force)')
    check_writable(o, what)
    return o


def check_writable(out, what: str = 'output') -> None:
    """
    Refuse, before any work, an output that cannot be created.

    A file is created and removed in its directory (or, where that does not exist yet, in the
    nearest existing one, whose subdirectories the writer creates). A read-only file system, a
    directory without write permission or a path through a file is one :class:`OSError` line
    naming the output.
    """
    o = Path(out)
    d = o.parent if str(o.parent) else Path('.')
    while not d.exists() and d != d.parent:
        d = d.parent
    try:
        if not d.is_dir():
            raise NotADirectoryError(20, 'not a directory')
        fd, probe = tempfile.mkstemp(prefix='.' + o.name + '.', suffix='.probe', dir=str(d))
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise OSError(f'{o}: the {what} cannot be written ({exc.strerror or exc}: {d})') \
            from None


def write_atomic(path, text: str) -> None:
    """Write ``text`` to a temporary file in ``path``'s directory and rename it into place."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix='.' + p.name + '.', suffix='.tmp', dir=str(p.parent))
    try:
        with os.fdopen(fd, 'w', encoding='utf-8') as f:
            f.write(text)
        umask = os.umask(0o22)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


PART_SUFFIX = '.part'


def partial_path(path) -> Path:
    """
    Where :class:`BagWriter` writes ``path`` until it is closed (``run.mcap.part``).

    A killed writer leaves its data there, and ``recover run.mcap`` finds it.
    """
    p = Path(path)
    return p.with_name(p.name + PART_SUFFIX)
