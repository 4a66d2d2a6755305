"""Every file a sub-command writes goes through here, so that no output loses or hides data.

- **Checked before the run** (:meth:`Outputs.check`, exit 2): an output's folder must exist and take a
  new file (tried with a temporary file: an existing output in a read-only folder cannot be replaced
  atomically), an existing output must be writable, an output must not be a directory (a report folder
  excepted), and no output may name an input (``--trace`` equal to LOG would overwrite the measurement)
  or another output.
- **Written after the results are printed**, each **atomically**: into a temporary file in the
  same folder, then ``os.replace`` onto the target, so a reader never sees half a file and a
  failed write leaves the old file as it was. A target that exists and is not a regular file
  (``/dev/null``, ``/dev/full``, a FIFO) is written in place: renaming onto it would replace the
  device itself.
- **A failed write is one line** naming the path and the operating system's error, no
  traceback; the other outputs are still written, and the command exits with
  :data:`EXIT_WRITE_FAILED`.
- **An output written as the run goes** (:class:`StreamedOutput`: ``listen --trace``, a run of hours
  that must not hold its trace in memory) goes into ``PATH.partial`` beside the target, flushed as it
  grows, and is renamed onto ``PATH`` when the run ends, by Ctrl-C, a signal or an internal error too. A
  killed process (SIGKILL, power loss) leaves ``PATH.partial`` with the rows it had flushed.
"""

from __future__ import annotations

import os
import shutil
import stat
import sys
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

from online_id.errors import OnlineIdError
from online_id.util.jsonio import json_text  # noqa: F401 - the writer every output uses, here for the commands

#: Exit status when the run itself went through but an output could not be written. Not 2: the
#: input was fine; not 1, which ``listen`` and ``replay`` use for a lost bus.
EXIT_WRITE_FAILED = 4


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def _is_special(path: Path) -> bool:
    """An existing target that is not a regular file or a directory (a device, a FIFO, a socket)."""
    try:
        mode = path.stat().st_mode
    except OSError:
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


def _existing_folder(folder: Path) -> Path:
    """``folder``, or its nearest existing ancestor (a folder an output will create)."""
    folder = Path(folder)
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    return folder


def _cannot_create_in(folder: Path) -> str | None:
    """None when a file can be made in ``folder`` (made and removed at once), else the operating system's
    reason."""
    try:
        fd, name = tempfile.mkstemp(prefix=".online-id-check.", suffix=".tmp", dir=folder)
    except OSError as exc:
        return _os_error(exc)
    os.close(fd)
    try:
        os.unlink(name)
    except OSError:
        pass
    return None


def _os_error(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return f"{type(exc).__name__}: {exc}"


class Outputs:
    """The outputs of one command: check them against the inputs, then write each one safely.

    ``failed`` lists the paths whose write failed; :meth:`status` is the exit status that says so.
    """

    def __init__(self, announce: bool = True) -> None:
        self.announce = announce  # print "wrote PATH" after each successful write
        self.failed: list[Path] = []

    # -- before the run -------------------------------------------------------------------------------
    @staticmethod
    def check(outputs: dict[str, Path | None], inputs: dict[str, Path | None] | None = None,
              folders: Iterable[str] = ()) -> None:
        """Refuse, before anything runs, outputs that cannot or must not be written.

        ``outputs`` and ``inputs`` map a flag (``--json``, ``LOG``) to its path (None: not given);
        the flags in ``folders`` name output directories (``--report``).
        """
        folders = set(folders)
        given = [(flag, Path(p)) for flag, p in outputs.items() if p is not None]
        sources = [(flag, Path(p)) for flag, p in (inputs or {}).items() if p is not None]
        for i, (flag, path) in enumerate(given):
            for in_flag, src in sources:
                if _same_file(path, src):
                    raise OnlineIdError(f"{flag} {path}: is the input {in_flag}; writing it would destroy the"
                                        " input (choose another path)")
            for other_flag, other in given[:i]:
                if _same_file(path, other):
                    raise OnlineIdError(f"{flag} {path}: also given as {other_flag}; one would overwrite the other")
            parent = path.parent
            if not parent.exists():
                raise OnlineIdError(f"{flag} {path}: folder {parent} does not exist")
            if path.is_dir() and flag not in folders:
                raise OnlineIdError(f"{flag} {path}: is a directory")
            if flag in folders and path.exists() and not path.is_dir():
                raise OnlineIdError(f"{flag} {path}: exists and is not a directory")
            Outputs.check_writable(flag, path, folder=flag in folders)

    @staticmethod
    def check_writable(flag: str, path: Path, folder: bool = False) -> None:
        """Refuse ``path`` when what its write needs is not writable: the folder it goes in (an atomic write
        makes a temporary file there, then renames it: an existing file in a read-only folder cannot be
        replaced), the file itself when it exists (read-only: someone meant to keep it), and for an output
        folder the folder too. The folder is tried by making and removing a temporary file, so a read-only
        file system or a permission the process overrides on paper (root) is judged as the write will be."""
        path = Path(path)
        if _is_special(path):  # a device or FIFO is written in place
            if not os.access(path, os.W_OK):
                raise OnlineIdError(f"{flag} {path}: not writable (file permission)")
            return
        if path.exists() and not path.is_dir() and not os.access(path, os.W_OK):
            raise OnlineIdError(f"{flag} {path}: exists and is read-only (file permission); remove it or choose"
                                " another path")
        for where in ([path] if folder and path.is_dir() else []) + [_existing_folder(path.parent)]:
            problem = _cannot_create_in(where)
            if problem:
                raise OnlineIdError(f"{flag} {path}: folder {where} is not writable ({problem}): the output could"
                                    " not be written after the run")

    # -- after the run ----------------------------------------------------------------------------------
    def write_text(self, path: Path | None, text: str) -> bool:
        """Write ``text`` (UTF-8) to ``path`` atomically; False (and one line) when it failed."""
        def writer(tmp: Path) -> None:
            with open(tmp, "w", encoding="utf-8") as fh:
                fh.write(text)
                fh.flush()
                os.fsync(fh.fileno())

        return self.write_with(path, writer)

    def write_with(self, path: Path | None, writer: Callable[[Path], object]) -> bool:
        """Call ``writer(tmp)`` to write a temporary file beside ``path`` (same suffix, so a figure
        keeps its format), then rename it onto ``path``. True on success or when ``path`` is None."""
        if path is None:
            return True
        path = Path(path)
        if _is_special(path):
            return self._attempt(path, lambda: writer(path))
        tmp: Path | None = None

        def atomic():
            nonlocal tmp
            fd, name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
            os.close(fd)
            tmp = Path(name)
            writer(tmp)
            _keep_mode(path, tmp)
            os.replace(tmp, path)
            tmp = None

        try:
            return self._attempt(path, atomic)
        finally:
            if tmp is not None:
                tmp.unlink(missing_ok=True)

    def write_folder(self, folder: Path | None, writer: Callable[[Path], Iterable[Path]]) -> list[Path]:
        """``writer(tmp_dir)`` writes files into a temporary folder beside ``folder``; each is then
        renamed into ``folder`` (created if needed). Returns the paths written."""
        if folder is None:
            return []
        folder = Path(folder)
        written: list[Path] = []
        tmp_dir: Path | None = None

        def build():
            nonlocal tmp_dir
            tmp_dir = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".tmp", dir=folder.parent))
            files = list(writer(tmp_dir))
            folder.mkdir(exist_ok=True)
            for f in files:
                target = folder / Path(f).name
                os.replace(f, target)
                written.append(target)
                if self.announce:
                    print(f"wrote {target}", flush=True)

        try:
            self._attempt(folder, build, announce=False)
        finally:
            if tmp_dir is not None:
                shutil.rmtree(tmp_dir, ignore_errors=True)
        return written

    def _attempt(self, path: Path, action: Callable[[], object], announce: bool = True) -> bool:
        try:
            action()
        except (OSError, ValueError, RuntimeError) as exc:  # ValueError/RuntimeError: a writer's own checks
            self.failed.append(path)
            print(f"online-id: error: cannot write {path}: {_os_error(exc)}", file=sys.stderr, flush=True)
            return False
        if self.announce and announce:
            print(f"wrote {path}", flush=True)
        return True

    def status(self, ok: int = 0) -> int:
        """``ok`` when every write went through, else :data:`EXIT_WRITE_FAILED`."""
        return EXIT_WRITE_FAILED if self.failed else ok


def _keep_mode(path: Path, tmp: Path) -> None:
    """The replaced file keeps its permissions; a new one gets the usual ones (mkstemp makes 0600)."""
    try:
        mode = stat.S_IMODE(path.stat().st_mode)
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        mode = 0o666 & ~umask
    os.chmod(tmp, mode)


#: The suffix of a streamed output while it is written.
PARTIAL_SUFFIX = ".partial"


class StreamedOutput:
    """An output written while the command runs: ``file`` is ``PATH.partial`` (``PATH`` itself when it is a
    device or a FIFO), open for writing text; :meth:`finish` renames it onto ``PATH``, :meth:`discard`
    removes it. Checked beforehand by :meth:`Outputs.check` as any output."""

    def __init__(self, flag: str, path: Path):
        self.flag, self.path = flag, Path(path)
        self.special = _is_special(self.path)
        self.partial = self.path if self.special else self.path.with_name(self.path.name + PARTIAL_SUFFIX)
        self.done = False
        try:
            self.file = open(self.partial, "w", encoding="utf-8")  # noqa: SIM115 - closed by finish or discard
        except OSError as exc:
            raise OnlineIdError(f"{flag} {self.path}: cannot write {self.partial}: {_os_error(exc)}") from None

    def finish(self, outputs: Outputs) -> bool:
        """Close the file and rename it onto the path (``outputs`` reports it as any output): True when
        written."""
        if self.done:
            return True
        self.done = True

        def rename():
            self.file.close()
            if not self.special:
                _keep_mode(self.path, self.partial)
                os.replace(self.partial, self.path)

        return outputs._attempt(self.path, rename)

    def discard(self) -> None:
        """Close and remove the file (a run that ended before any result)."""
        if self.done:
            return
        self.done = True
        try:
            self.file.close()
        finally:
            if not self.special:
                self.partial.unlink(missing_ok=True)
