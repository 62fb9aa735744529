"""An output folder whose set of results is whole or absent.

A run writes every output into a staging folder inside the output folder
(``OUT/.pointrig-partial/``). Only when all of them are written does :meth:`OutputDir.commit`
move them into ``OUT``, one rename per file, and write ``OUT/manifest.json`` last: the
manifest names the one consistent set (every file with its size and SHA-256). While a commit
runs the old manifest is gone, so an interrupted commit leaves no set declared; files of the
previous set that the new one lacks are removed. A run that is killed before its commit leaves
the previous set untouched; its staging folder is removed by the next run (its registration
checkpoint is kept for that run to reuse).

The folder is checked before any work starts (not a file, writable, enough free space) and
locked (``OUT/.pointrig.lock``, an advisory ``flock``, removed when the run ends) so that a
second run into the same folder fails at once instead of mixing its files with the first's.
A folder the run created is removed again when the run fails before writing anything.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import re
import shutil
from pathlib import Path
from typing import IO

from ..errors import OutputError
from .atomic import write_json

__all__ = ["FAULT_ENV", "FRAMES", "LOCK", "MANIFEST", "MANIFEST_FORMAT", "PARTIAL", "STAGING",
           "OutputDir", "check_output_dir", "fault_point", "read_manifest"]

#: the file that names the complete set of outputs, written last
MANIFEST = "manifest.json"
MANIFEST_FORMAT = "pointrig.outputs/1"
#: the staging folder inside the output folder
STAGING = ".pointrig-partial"
#: the lock file inside the output folder
LOCK = ".pointrig.lock"
#: the staging folder's record of the files of earlier sets that a commit replaces (read by
#: the next commit when this one was interrupted: no manifest then names them)
REPLACED = ".replaced.json"
#: the frames an interrupted step 1 registered, in the staging folder (never committed)
PARTIAL = "registration.partial.npz"
#: the folder of the staging folder where the input frames wait on disk during a run
#: (:class:`pointrig.sequence.SpilledFrames`; a folder, so never committed)
FRAMES = ".frames"
#: files of the staging folder that are not outputs
PRIVATE = (REPLACED, PARTIAL)
#: files of the staging folder that an interrupted run leaves for the next one
KEEP_ON_RESTART = ("registration.npz", *PRIVATE)
#: the temporary files of :func:`pointrig.io.atomic.atomic_path`: ``.NAME.XXXXXXXX[SUFFIX]``
_ATOMIC_TEMP = re.compile(r"^\.(?P<name>.+)\.[a-z0-9_]{8}(?P<suffix>\.[A-Za-z0-9]+)?$")


def check_output_dir(path: str | Path, need_bytes: int = 0) -> Path:
    """Check, before any work, that ``path`` can hold the outputs: it is a folder or can be
    made one, it is writable and its file system has ``need_bytes`` free. Creates the folder.

    Raises
    ------
    OutputError
        The path is a file (or under one), not writable, or lacks the space; the message
        names the path and the problem.
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise OutputError("the output path is a file, not a folder", out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise OutputError("a part of the output path is a file, not a folder", out) from None
    except OSError as exc:
        raise OutputError(f"cannot create the output folder: {exc.strerror or exc}", out) \
            from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise OutputError("the output folder is not writable", out)
    try:
        probe = out / f".pointrig-probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise OutputError(f"cannot write into the output folder: {exc.strerror or exc}", out) \
            from None
    _require_space(out, need_bytes)
    return out


def _require_space(out: Path, need_bytes: int) -> None:
    free = shutil.disk_usage(out).free
    if need_bytes > free:
        raise OutputError(f"{free / 1e6:.1f} MB free, the outputs need about "
                          f"{need_bytes / 1e6:.1f} MB", out)


def read_manifest(path: str | Path) -> dict[str, dict]:
    """The files of the complete output set in folder ``path`` (``{name: {"bytes": n,
    "sha256": hex}}``), or ``{}`` when no complete set is declared there."""
    try:
        doc = json.loads((Path(path) / MANIFEST).read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(doc, dict) or doc.get("format") != MANIFEST_FORMAT:
        return {}
    files = doc.get("files")
    return files if isinstance(files, dict) else {}


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class OutputDir:
    """The output folder of one run: checked, locked, with a staging folder for the outputs.

    Use as a context manager; write every output under :attr:`stage`, then call
    :meth:`commit`. Leaving the block without a commit (an error) removes the staging folder's
    outputs and leaves the folder's previous set as it was.

    Parameters
    ----------
    path
        The output folder (created when missing).
    need_bytes
        Free space the outputs need, bytes (checked at once).
    """

    def __init__(self, path: str | Path, need_bytes: int = 0):
        self._created = not Path(path).exists()
        self.path = check_output_dir(path, need_bytes)
        self.stage = self.path / STAGING
        self._lock: IO[bytes] | None = None

    # -- lock --------------------------------------------------------------------------------
    def __enter__(self) -> OutputDir:
        self._acquire()
        try:
            self._clean_stale()
        except BaseException:
            self._release()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            if self.stage.exists():
                self._clear_stage(keep=KEEP_ON_RESTART if exc[0] is not None else ())
        finally:
            self._release()
        if self._created:  # a folder this run made and left empty (a failed run) goes again
            with contextlib.suppress(OSError):
                self.path.rmdir()

    def _acquire(self) -> None:
        try:
            import fcntl
        except ImportError:  # no advisory locks on this platform: run unlocked
            return
        try:
            fh = open(self.path / LOCK, "a+b")  # noqa: SIM115 - held until _release
        except OSError as exc:
            raise OutputError(f"cannot create the lock file: {exc.strerror or exc}",
                              self.path) from None
        busy = OutputError("another pointrig run is writing into this output folder; wait "
                           "for it or choose another folder", self.path)
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            fh.close()
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise busy from None
            raise OutputError(f"cannot lock the output folder: {exc.strerror or exc}",
                              self.path) from None
        # the holder removes the lock file when done: a lock taken on a file that was removed
        # meanwhile is no lock (another run may hold a new file of the same name)
        try:
            same = os.stat(self.path / LOCK).st_ino == os.fstat(fh.fileno()).st_ino
        except OSError:
            same = False
        if not same:
            fh.close()
            raise busy
        self._lock = fh

    def _release(self) -> None:
        if self._lock is not None:
            with contextlib.suppress(OSError):
                (self.path / LOCK).unlink()  # while still held (see _acquire)
            self._lock.close()  # closing the file releases the flock
            self._lock = None

    # -- staging ------------------------------------------------------------------------------
    def _clean_stale(self) -> None:
        """Remove what interrupted runs left: the staging folder's outputs (not the
        registration checkpoint, which this run may reuse) and the temporary files of
        :func:`pointrig.io.atomic.atomic_path` in the folder itself."""
        for p in self.path.iterdir():
            m = _ATOMIC_TEMP.match(p.name)
            if m and p.is_file() and (m["suffix"] or "") == Path(m["name"]).suffix:
                p.unlink(missing_ok=True)
        if self.stage.exists() and not self.stage.is_dir():
            self.stage.unlink()
        if self.stage.exists():
            self._clear_stage(keep=KEEP_ON_RESTART)
        self.stage.mkdir(exist_ok=True)

    def _clear_stage(self, keep: tuple[str, ...] = ()) -> None:
        for p in sorted(self.stage.iterdir()):
            if p.name in keep and p.is_file():
                continue
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink(missing_ok=True)
        if not any(self.stage.iterdir()):
            self.stage.rmdir()

    def _replaced(self) -> set[str]:
        """The file names of earlier sets an interrupted commit was replacing."""
        try:
            names = json.loads((self.stage / REPLACED).read_text())
        except (OSError, ValueError):
            return set()
        return {n for n in names if isinstance(n, str)} if isinstance(names, list) else set()

    def require_space(self, need_bytes: int) -> None:
        """Check that the folder's file system has ``need_bytes`` free (:class:`OutputError`
        otherwise)."""
        _require_space(self.path, need_bytes)

    def staged(self, name: str) -> Path:
        """Where to write output ``name`` (a file name in the output folder)."""
        return self.stage / name

    def resume_candidates(self, name: str) -> list[Path]:
        """The existing copies of ``name`` a run may reuse, best first: the one an
        interrupted run left in the staging folder, then the committed one."""
        return [p for p in (self.stage / name, self.path / name) if p.is_file()]

    def carry(self, name: str) -> None:
        """Make the committed ``name`` part of the new set too (a hard link, or a copy)."""
        src, dst = self.path / name, self.stage / name
        if dst.exists() or not src.is_file():
            return
        try:
            os.link(src, dst)
        except OSError:
            shutil.copy2(src, dst)

    # -- commit -------------------------------------------------------------------------------
    def commit(self) -> dict[str, Path]:
        """Move every file of the staging folder into the output folder and write the
        manifest naming them. Returns ``{name: final path}``."""
        names = sorted(p.name for p in self.stage.iterdir()
                       if p.is_file() and p.name not in PRIVATE)
        entries = {n: {"bytes": (self.stage / n).stat().st_size,
                       "sha256": _sha256(self.stage / n)} for n in names}
        old = set(read_manifest(self.path)) | self._replaced()
        # the old names first, so that a commit interrupted below is finished by the next one
        write_json(self.stage / REPLACED, sorted(old))
        (self.path / MANIFEST).unlink(missing_ok=True)  # from here no set is declared
        for n in old:
            if n not in entries and "/" not in n and n not in (MANIFEST, LOCK, STAGING):
                (self.path / n).unlink(missing_ok=True)
        for i, n in enumerate(names):
            fault_point(f"commit:{i}")
            os.replace(self.stage / n, self.path / n)
        write_json(self.path / MANIFEST, {"format": MANIFEST_FORMAT, "files": entries})
        return {n: self.path / n for n in names}


#: The environment variable of the fault tests: a process reaching the named point of a run
#: kills itself with SIGKILL (as a power cut or ``kill -9`` would stop it there).
FAULT_ENV = "POINTRIG_KILL_AT"


def fault_point(name: str) -> None:
    """Die at once when :data:`FAULT_ENV` names this point (fault tests only)."""
    if os.environ.get(FAULT_ENV) == name:
        import signal

        os.kill(os.getpid(), signal.SIGKILL)
