"""The output folder of a run: what a run may delete there, and one run at a time.

A run marks its folder with a manifest, ``.fenics-adaptive-run.json``: the relative path of
every file and folder it writes there, added before the file is created, so that the list
holds all the program's files even after a kill. A fresh run into the folder then removes
exactly what the manifest lists (folders only if they end up empty) and nothing else, and it
refuses a non-empty folder without a manifest (``InputError`` on ``--out``) unless
``overwrite`` is given; even then only the program's own file names (``is_own_name``) go,
never other files. Files with the program's names that the manifest does not list are
treated alike: refused, or removed with ``overwrite``.

While a run writes, it holds ``.fenics-adaptive.lock``, created with ``O_EXCL`` and holding
the PID, host and start time of the run. A second run into the folder is refused with those;
a lock whose process is gone (same host, PID not alive, or alive but started at another
moment: a reused PID) is stale and taken over with a notice on stderr. Under MPI only rank 0
touches the folder; every step that can fail is shared (``errors.shared_errors``), so all
ranks raise the same error.
"""

from __future__ import annotations

import errno
import json
import os
import re
import secrets
import socket
import sys
import time
from pathlib import Path, PurePosixPath

from mpi4py import MPI

import fenics_adaptive
from fenics_adaptive.errors import InputError, shared_errors

MANIFEST = ".fenics-adaptive-run.json"
LOCK = ".fenics-adaptive.lock"

# The names the program gives to what it writes, as paths relative to the run folder. One
# table for both --overwrite and the check that no such file is left unlisted.
# (displacement.bp/: the ADIOS2 folder earlier versions wrote, still removed by --overwrite)
_FIELDS = (
    r"elements\.pvd|plies\.pvd|cohesive\.pvd|displacement\.xdmf|displacement\.h5"
    r"|(elements|plies|cohesive)/(elements|plies|cohesive)_\d+(_r\d+)?\.p?vtu"
    r"|displacement\.bp/(data\.\d+|md\.\d+|md\.idx|mmd\.\d+|profiling\.json)"
)
_OWN_FILE = re.compile(
    r"(history(\.partial)?\.csv|interlaminar_stresses\.csv|summary\.json(\.partial)?|force_displacement\.png|energies\.png"
    r"|checkpoint(\.partial|\.old)?/(checkpoint\.json(\.partial)?|rank\d+(-\d+)?\.npz"
    r"|history-\d+\.csv)"
    rf"|{_FIELDS}|restart_step\d+/({_FIELDS}))"
)
_OWN_FOLDER = re.compile(
    r"((restart_step\d+/)?(displacement\.bp|elements|plies|cohesive)|checkpoint(\.partial|\.old)?"
    r"|restart_step\d+)"
)
# folders a library fills with files of its own naming (ADIOS2): a listed folder of this kind
# gives its own-named files to the run that listed it
_LIBRARY_FOLDER = re.compile(r"(restart_step\d+/)?displacement\.bp")

_ACTIVE: set[str] = set()  # tokens of the locks this process holds now


def is_own_name(relative: str) -> bool:
    """Whether a path relative to a run folder ("elements/elements_000003.vtu") is one of the
    names this program writes."""
    return _OWN_FILE.fullmatch(relative) is not None


def own_files(folder: Path) -> list[str]:
    """The files in ``folder`` with the program's names (relative posix paths, sorted); only
    the program's own subfolders are searched."""
    found = []

    def visit(directory: Path, prefix: str) -> None:
        for entry in sorted(directory.iterdir()):
            relative = prefix + entry.name
            if entry.is_dir() and not entry.is_symlink():
                if _OWN_FOLDER.fullmatch(relative):
                    visit(entry, relative + "/")
            elif is_own_name(relative):
                found.append(relative)

    visit(folder, "")
    return found


def _safe_relative(entry: object) -> str | None:
    """A manifest entry as a relative posix path inside the folder, or None if it is not one
    (absolute, '..', not a string)."""
    if not isinstance(entry, str) or not entry:
        return None
    path = PurePosixPath(entry.rstrip("/"))
    if path.is_absolute() or ".." in path.parts or str(path) in ("", "."):
        return None
    return str(path) + ("/" if entry.endswith("/") else "")


def read_manifest(folder: Path) -> list[str] | None:
    """The entries of the folder's manifest (folders end in '/'), or None without one. Raises
    InputError naming the file if it cannot be read."""
    path = folder / MANIFEST
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text())
        entries = data["written"]
        if data.get("program") != "fenics-adaptive" or not isinstance(entries, list):
            raise ValueError("not a fenics-adaptive run manifest")
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise InputError(
            "--out",
            f"{path} cannot be read ({error}); remove it, or give --overwrite to replace only "
            "this program's own result files",
        ) from None
    return [e for e in (_safe_relative(x) for x in entries) if e is not None]


def _process_start(pid: int) -> str | None:
    """The start time of a process in clock ticks since boot (Linux /proc), None if unknown."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat.rsplit(")", 1)[1].split()[19]  # field 22: starttime


def _alive(pid: int, start: str | None) -> bool:
    """Whether process ``pid`` on this host is the one that was started at ``start``."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # another user's process: it exists
    now = _process_start(pid)
    return start is None or now is None or now == start


def _describe(info: dict) -> str:
    return f"PID {info.get('pid')} on {info.get('host')}, started {info.get('started')}"


class RunFolder:
    """The output folder of one run: checked before the model is built (``check``), then
    locked and prepared (``open``), written (``record`` each name before writing it), and
    released (``close``).

    Parameters:
        path: the folder (created if needed).
        comm: the run's communicator; rank 0 does the file work.
        overwrite: allow a non-empty folder without a manifest (only the program's own file
            names are removed from it).
    """

    def __init__(self, path: str | Path, comm: MPI.Comm, overwrite: bool = False):
        self.path = Path(path)
        self.comm = comm
        self.overwrite = overwrite
        self.entries: set[str] = set()
        self.token: str | None = None
        self.root = comm.rank == 0

    # ------------------------------------------------------------------ checks
    def check(self, fresh: bool) -> None:
        """Collective, read-only: refuse (InputError on ``--out``) a path that is a file, a
        folder another run holds, or (``fresh``: the run starts there) a folder this run may
        not prepare; a folder that does not exist must be creatable."""
        with shared_errors(self.comm):
            if self.root:
                self._check(fresh)

    def _check(self, fresh: bool) -> None:
        path = self.path
        longest = max(len(os.fsencode(part)) for part in path.absolute().parts)
        if longest > 255 or len(os.fsencode(path.absolute())) > 4095:  # NAME_MAX, PATH_MAX
            raise InputError("--out", f"{str(path)[:60]}...: the name is too long for a folder")
        if path.exists() and not path.is_dir():
            raise InputError("--out", f"{path} exists and is not a folder")
        if not path.exists():
            parent = path.absolute().parent
            while not parent.exists():
                parent = parent.parent
            if not parent.is_dir():
                raise InputError("--out", f"cannot create {path}: {parent} is not a folder")
            if not os.access(parent, os.W_OK | os.X_OK):
                raise InputError("--out", f"cannot create {path}: {parent} is not writable")
            return
        if not os.access(path, os.W_OK | os.X_OK):
            raise InputError("--out", f"{path} is not writable")
        holder = self._live_lock()
        if holder is not None:
            raise self._in_use(holder)
        if fresh:
            self._removals()

    def _in_use(self, info: dict) -> InputError:
        return InputError(
            "--out",
            f"{self.path} is in use by another run ({_describe(info)}); wait for it to end, "
            f"or remove {self.path / LOCK} if that run is gone",
        )

    def _removals(self) -> tuple[list[str], list[str]]:
        """(files, folders) a fresh run removes, relative; raises InputError if the folder
        may not be prepared. Only the program's own names are ever removed, even if a
        manifest lists others."""
        try:
            listed = read_manifest(self.path)
        except InputError:
            if not self.overwrite:
                raise
            listed = None  # --overwrite: an unreadable manifest is replaced
        others = [e.name for e in sorted(self.path.iterdir()) if not _bookkeeping(e.name)]
        if listed is None and others and not self.overwrite:
            shown = ", ".join(others[:3]) + (", ..." if len(others) > 3 else "")
            raise InputError(
                "--out",
                f"{self.path} is not empty ({shown}) and is not a fenics-adaptive run folder "
                f"(no {MANIFEST}); choose a new or empty folder, or give --overwrite to "
                "replace only this program's own result files",
            )
        listed = listed or []
        files = [e for e in listed if not e.endswith("/")]
        folders = [e.rstrip("/") for e in listed if e.endswith("/")]
        for folder in folders:
            if _LIBRARY_FOLDER.fullmatch(folder) and (self.path / folder).is_dir():
                files += [f"{folder}/{e.name}" for e in (self.path / folder).iterdir()]
        files = [f for f in dict.fromkeys(files) if is_own_name(f)]
        unlisted = [f for f in own_files(self.path) if f not in files]
        if unlisted and not self.overwrite:
            shown = ", ".join(unlisted[:3]) + (", ..." if len(unlisted) > 3 else "")
            raise InputError(
                "--out",
                f"{self.path} holds files with this program's names that its run manifest "
                f"does not list ({shown}); give --overwrite to replace them",
            )
        for name in unlisted:  # their folders go too, if they end up empty
            parts = name.split("/")[:-1]
            folders += ["/".join(parts[: k + 1]) for k in range(len(parts))]
        return files + unlisted, list(dict.fromkeys(folders))

    # ------------------------------------------------------------------ lock
    def _read_lock(self) -> dict | None:
        """The lock's content; None if there is no lock. Unreadable content is retried for a
        moment (a run may be writing it just now), then returned as {} (no owner)."""
        for _ in range(20):
            try:
                return json.loads((self.path / LOCK).read_text())
            except FileNotFoundError:
                return None
            except (OSError, ValueError):
                time.sleep(0.05)
        return {}

    def _stale(self, info: dict) -> bool:
        if not info:
            age = time.time() - (self.path / LOCK).stat().st_mtime
            return age > 10.0  # written by no live run (it would have been completed by now)
        if info.get("host") != socket.gethostname():
            return False  # cannot tell: the other host's run may be alive
        pid = info.get("pid")
        if not isinstance(pid, int):
            return True
        if pid == os.getpid():  # left by an earlier run of this process, if not active now
            return info.get("token") not in _ACTIVE
        return not _alive(pid, info.get("process_start"))

    def _live_lock(self) -> dict | None:
        try:
            info = self._read_lock()
        except OSError:
            return None
        if info is None:
            return None
        try:
            return None if self._stale(info) else info
        except FileNotFoundError:
            return None

    def _acquire(self) -> None:
        lock = self.path / LOCK
        self.token = secrets.token_hex(8)
        info = {
            "program": "fenics-adaptive",
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": time.strftime("%Y-%m-%d %H:%M:%S %z"),
            "process_start": _process_start(os.getpid()),
            "token": self.token,
        }
        for _ in range(10):
            try:
                fd = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                held = self._read_lock()
                if held is None:
                    continue  # released meanwhile
                try:
                    stale = self._stale(held)
                except FileNotFoundError:
                    continue  # released meanwhile
                if not stale:
                    raise self._in_use(held) from None
                self._take_over(held)
                continue
            with os.fdopen(fd, "w") as f:
                f.write(json.dumps(info) + "\n")
                f.flush()
                os.fsync(f.fileno())
            _ACTIVE.add(self.token)
            return
        raise InputError("--out", f"could not take the lock {lock}: other runs keep taking it")

    def _take_over(self, stale: dict) -> None:
        """Remove a stale lock; if another run replaced it meanwhile, put that one back."""
        lock = self.path / LOCK
        aside = self.path / f"{LOCK}.stale-{os.getpid()}"
        try:
            os.replace(lock, aside)
        except FileNotFoundError:
            return
        try:
            moved = json.loads(aside.read_text())
        except (OSError, ValueError):
            moved = {}
        if moved != stale:  # a live run's fresh lock: give it back (unless taken again)
            try:
                os.link(aside, lock)
            except FileExistsError:
                pass
            aside.unlink(missing_ok=True)
            return
        aside.unlink(missing_ok=True)
        print(
            f"fenics-adaptive: {self.path}: taking over the stale lock of a run that is gone "
            f"({_describe(stale) if stale else 'no owner recorded'})",
            file=sys.stderr,
        )

    def _release(self) -> None:
        if self.token is None:
            return
        lock = self.path / LOCK
        try:
            if json.loads(lock.read_text()).get("token") == self.token:
                lock.unlink()
        except (OSError, ValueError):
            pass
        _ACTIVE.discard(self.token)
        self.token = None

    # ------------------------------------------------------------------ preparation
    def open(self, fresh: bool) -> None:
        """Collective: create the folder, take its lock and, for a ``fresh`` run, remove the
        previous run's files (only those: see the module). A run that continues in the folder
        (restart) keeps them and adds to the manifest."""
        with shared_errors(self.comm):
            if self.root:
                self._check(fresh)
                try:
                    self.path.mkdir(parents=True, exist_ok=True)
                except OSError as error:
                    raise InputError(
                        "--out", f"cannot create {self.path}: {error.strerror}"
                    ) from None
                self._acquire()
                try:
                    if fresh:
                        files, folders = self._removals()
                        self._remove(files, folders)
                        self.entries = set()
                    else:
                        try:
                            self.entries = set(read_manifest(self.path) or [])
                        except InputError:
                            if not self.overwrite:
                                raise
                            self.entries = set()  # --overwrite: an unreadable one replaced
                    self._write_manifest()
                except BaseException:
                    self._release()
                    raise

    def _remove(self, files: list[str], folders: list[str]) -> None:
        for relative in files:
            path = self.path / relative
            if path.is_file() or path.is_symlink():
                path.unlink()
        # deepest first; a folder that still holds anything stays
        for relative in sorted(set(folders), key=lambda f: -f.count("/")):
            try:
                (self.path / relative).rmdir()
            except FileNotFoundError:
                pass
            except OSError as error:
                if error.errno not in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR):
                    raise

    def remove_recorded(self, under: str) -> None:
        """Collective: remove the files the manifest lists below the relative folder ``under``
        (e.g. the fields of an earlier restart from the same checkpoint)."""
        with shared_errors(self.comm):
            if self.root:
                prefix = under.rstrip("/") + "/"
                files = [e for e in self.entries if e.startswith(prefix) and is_own_name(e)]
                folders = [e.rstrip("/") for e in self.entries if e.startswith(prefix)]
                for folder in folders:
                    if _LIBRARY_FOLDER.fullmatch(folder) and (self.path / folder).is_dir():
                        files += [
                            f"{folder}/{e.name}"
                            for e in (self.path / folder).iterdir()
                            if is_own_name(f"{folder}/{e.name}")
                        ]
                self._remove(files, folders)
                self.entries -= {*files, *(f + "/" for f in folders)}
                self._write_manifest()

    def record(self, *paths: str | Path, folder: bool = False) -> None:
        """Add paths in the folder (as ``folder.path / name``) to the manifest before they
        are written; ``folder``: they are folders. Rank 0 only; a no-op on the other ranks."""
        if not self.root:
            return
        new = set()
        for path in paths:
            relative = Path(os.path.abspath(path)).relative_to(os.path.abspath(self.path))
            if relative == Path("."):
                continue  # the run folder itself: never removed
            name = relative.as_posix() + ("/" if folder else "")
            if name not in self.entries:
                new.add(name)
                if "/" in name.rstrip("/"):  # its parent folders, for the removal
                    parts = name.rstrip("/").split("/")[:-1]
                    new.update("/".join(parts[: k + 1]) + "/" for k in range(len(parts)))
        new -= self.entries
        if new:
            self.entries |= new
            self._write_manifest()

    def forget(self, *paths: str | Path) -> None:
        """Drop files the run has removed itself from the manifest (rank 0; a no-op on the
        other ranks)."""
        if not self.root:
            return
        names = {Path(os.path.relpath(p, self.path)).as_posix() for p in paths}
        if names & self.entries:
            self.entries -= names
            self._write_manifest()

    def _write_manifest(self) -> None:
        data = {
            "program": "fenics-adaptive",
            "about": "what fenics-adaptive wrote into this folder; a new run into it removes "
            "these and nothing else",
            "version": fenics_adaptive.__version__,
            "written": sorted(self.entries),
        }
        tmp = self.path / (MANIFEST + ".partial")
        tmp.write_text(json.dumps(data, indent=1) + "\n")
        os.replace(tmp, self.path / MANIFEST)

    def close(self) -> None:
        """Release the lock (rank 0); not collective, so it can run on any way out."""
        if self.root:
            self._release()


def _bookkeeping(name: str) -> bool:
    """The folder's manifest and lock files (also their temporary and set-aside forms)."""
    return name.startswith((MANIFEST, LOCK))
