"""Atomic file writing (a crash never leaves a half-written file under the final name), run folders, the
key of every on-disk cache (:func:`source_digest`) and paths named for what is wrong with them
(:func:`explain_path`), and worker processes that leave a Ctrl-C to their command (:func:`quiet_worker`)."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import IO, Any


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _default_mode() -> int:
    """The mode a plain ``open(..., "w")`` would give (mkstemp makes files private)."""
    return 0o666 & ~_umask()


def _default_dir_mode() -> int:
    """The mode a plain ``mkdir`` would give (mkdtemp makes folders private)."""
    return 0o777 & ~_umask()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path in the same folder; on success it is renamed onto ``path``."""
    from .errors import path_like

    path = path_like("path", path)
    _not_special(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, _default_mode())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _not_special(path: Path) -> None:
    """:class:`~vtol_impedance.errors.InputError` when ``path`` is something a file written there would
    replace but is not a file: a folder, a device (``/dev/null``: renamed onto as root, the machine's would
    become a file), a FIFO or a socket; or lies in a live flight's recording (:func:`is_recording`)."""
    import stat

    from .errors import InputError

    if is_recording(path.absolute().parent):
        raise InputError(
            f"{path} is inside {path.absolute().parent}, a live flight's recording (written by `vtol-impedance "
            "live`), which no command may change; give a path outside it"
        )
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return  # nothing there (or a dangling link): a new file
    if stat.S_ISREG(mode):
        return
    kind = ("a folder" if stat.S_ISDIR(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "not a regular file")  # fmt: skip
    raise InputError(f"{path} is {kind}, not a file: writing there would replace it; give the path of a file")


def check_output_file(path: str | os.PathLike[str]) -> Path:
    """``path`` as a :class:`~pathlib.Path` when a file can be written there (new, or a regular file to
    replace), else :class:`~vtol_impedance.errors.InputError` naming what is in the way (a folder, a device,
    a FIFO; a folder on the way that cannot be made or written). Cheap: commands call it before any work."""
    from .errors import InputError, path_like

    path = path_like("path", path)
    if not str(path).strip():
        raise InputError("give the path of a file to write")
    _not_special(path)
    for parent in path.absolute().parents:  # the first existing folder up the path must take a new file
        if parent.exists():
            if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
                raise InputError(f"{path}: {parent} is not a folder this user can write into")
            try:  # not /proc, not a read-only mount
                with tempfile.NamedTemporaryFile(dir=parent, prefix=".vtol-probe-"):
                    pass
            except OSError as exc:
                raise InputError(f"{path}: cannot write into {parent} ({exc.strerror or exc})") from None
            break
    return path


def write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (see :func:`atomic_path`); return the path."""
    from .errors import instance, path_like

    path = path_like("path", path)
    instance("text", text, str)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def write_with(path: str | os.PathLike[str], writer: Callable[[IO[bytes]], None]) -> Path:
    """Call ``writer(file)`` on a binary temporary file, then move it into place."""
    from .errors import function, path_like

    path = path_like("path", path)
    function("writer", writer)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        writer(fh)
        fh.flush()
        os.fsync(fh.fileno())
    return Path(path)


# --------------------------------------------------------------------------- worker processes


def quiet_worker(die_with_parent: bool = True) -> None:
    """A worker process's initializer (the paper's flights, the tuning page's margins): ignore SIGINT,
    which a Ctrl-C sends to the whole process group while the command alone answers it (stopping its
    workers, without one traceback per worker); with ``die_with_parent``, be killed when the parent dies,
    however it dies (Linux ``PR_SET_PDEATHSIG``). That signal follows the *thread* that started the worker:
    a pool whose workers a passing thread may start (a web server's request) must not ask for it."""
    import ctypes
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # discards one held back by spawning_quietly
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    if die_with_parent:
        try:
            ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG = 1
        except (OSError, AttributeError):
            pass


@contextlib.contextmanager
def spawning_quietly() -> Iterator[None]:
    """Around a process pool's ``submit`` calls, which start its workers: SIGINT is held back in this
    thread and so in the workers it starts, until their :func:`quiet_worker` ignores it (a Ctrl-C while a
    worker imports Python would otherwise print that worker's traceback). A Ctrl-C the kernel gives this
    thread waits until the block ends, a few milliseconds (another thread may take it at once)."""
    import signal

    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


# --------------------------------------------------------------------------- on-disk caches


def source_digest(sources: Iterable[str | os.PathLike[str]]) -> str:
    """The key of an on-disk cache: SHA-256 of the package version and of every file in ``sources`` (the
    code that computes the cached content; a missing file counts as empty).

    Every cache the package keeps on disk (the compiled kernels, the robust designs) is keyed by it, so an
    edit of that code or an installed upgrade is never answered from entries the old code wrote.
    """
    from .errors import InputError, path_like

    if isinstance(sources, str | bytes | os.PathLike) or not hasattr(sources, "__iter__"):
        raise InputError(f"sources must be a sequence of file paths, got {sources!r:.80}")
    sources = [path_like("sources[]", p) for p in sources]
    import hashlib

    from . import __version__

    h = hashlib.sha256(f"vtol-impedance {__version__}\n".encode())
    for p in sources:
        p = Path(p)
        try:
            data = p.read_bytes()
        except OSError:
            data = b""
        h.update(f"{p.name} {len(data)}\n".encode())
        h.update(data)
    return h.hexdigest()


# --------------------------------------------------------------------------- paths named for what is wrong


def explain_path(path: str | os.PathLike[str], need: str = "file") -> str | None:
    """What makes ``path`` unusable, in words that name the user's path and its culprit, or None.

    ``need`` is ``"file"`` (a file to read: it must exist and be readable) or ``"folder"`` (an output folder:
    it may be missing, but every existing part of it must be a folder, reachable, and the first missing
    part's parent writable). Named: a symbolic link loop, a dangling link, a part of the path that is a file
    where a folder is needed, a folder that cannot be searched, read or written (permission), a missing file.
    """
    import errno

    from .errors import choice, path_like

    path = path_like("path", path)
    choice("need", need, ("file", "folder"))
    parts = [path, *path.parents][::-1]  # from the root (or the first relative part) down to ``path``
    if not path.is_absolute():
        parts = [p for p in parts if str(p) != "."]
    prev: Path | None = None
    for part in parts:
        last = part == parts[-1]
        try:
            st = os.lstat(part)
        except FileNotFoundError:
            if need == "folder":
                base = prev if prev is not None else Path.cwd()
                if not os.access(base, os.W_OK | os.X_OK):
                    return f"{base} is not writable (permission denied), so {part} cannot be created"
                return None
            return f"{part} does not exist" if last else f"{part} does not exist (a folder on the way to {path})"
        except PermissionError:
            return f"{prev} cannot be searched (permission denied), so {part} cannot be reached"
        except OSError as exc:
            if exc.errno == errno.ENOTDIR:
                return f"{path} has {prev} in its path, which is a file, not a folder"
            if exc.errno == errno.ELOOP:
                return f"{part} is a symbolic link loop"
            if exc.errno == errno.ENAMETOOLONG:
                return f"{path} is too long a path for the file system"
            return f"{part}: {exc.strerror}"
        import stat as _stat

        if _stat.S_ISLNK(st.st_mode):
            try:
                st = os.stat(part)
            except OSError as exc:
                if exc.errno == errno.ELOOP:
                    return f"{part} is a symbolic link loop (it points back to itself)"
                if exc.errno == errno.ENOENT:
                    return f"{part} is a symbolic link to {os.readlink(part)}, which does not exist"
                return f"{part} is a symbolic link that cannot be followed ({exc.strerror})"
        is_dir = _stat.S_ISDIR(st.st_mode)
        if not last and not is_dir:
            return f"{path} has {part} in its path, which is a file, not a folder"
        if not last and not os.access(part, os.X_OK):
            return f"{part} cannot be searched (permission denied)"
        if last and need == "file":
            if is_dir:
                return f"{part} is a folder, not a file"
            if not os.access(part, os.R_OK):
                return f"{part} is not readable (permission denied)"
        if last and need == "folder":
            if not is_dir:
                return f"{part} is a file (or a device), not a folder"
            if not os.access(part, os.W_OK | os.X_OK):
                return f"{part} is not writable (permission denied)"
        prev = part
    return None


def input_file(path: str | os.PathLike[str], what: str) -> Path:
    """``path`` as a :class:`~pathlib.Path` when it is a readable file, else
    :class:`~vtol_impedance.errors.InputError` naming ``what`` it is (``"log file"``), the path and why."""
    from .errors import InputError, instance

    instance("what", what, str)
    if not isinstance(path, str | os.PathLike):
        raise InputError(f"{what} must be a path (str or os.PathLike), got {type(path).__name__} {path!r}")
    why = explain_path(path, "file")
    if why:
        raise InputError(f"cannot read {what} {path}: {why}")
    return Path(path)


def read_toml(path: str | os.PathLike[str], what: str, error: type[Exception] | None = None) -> dict[str, Any]:
    """The TOML file at ``path`` as a dict, or ``error`` (default
    :class:`~vtol_impedance.errors.InputError`) naming ``what`` it is, the path and why: unreadable (see
    :func:`explain_path`), not UTF-8, malformed, or nested deeper than the reader can follow."""
    from .errors import InputError, instance, path_like

    path = path_like("path", path)
    instance("what", what, str)
    error = error or InputError
    try:
        text = Path(path).read_text(encoding="utf-8-sig")  # a Windows editor's byte-order mark is not text
    except OSError as exc:
        raise error(f"cannot read {what} {path}: {explain_path(path, 'file') or exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise error(f"cannot read {what} {path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    return parse_toml(text, f"{what} {path}", error)


def parse_toml(text: str, where: str, error: type[Exception] | None = None) -> dict[str, Any]:
    """``tomllib.loads(text)``, with a malformed or too deeply nested text an ``error`` naming ``where``."""
    import tomllib

    from .errors import InputError, instance

    instance("text", text, str)
    instance("where", where, str)
    error = error or InputError
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"cannot read {where}: {exc}") from None
    except RecursionError:
        raise error(
            f"cannot read {where}: its arrays or tables are nested too deeply for the TOML reader (no value "
            "of this tool nests more than three levels)"
        ) from None


def user_path(filename: str | os.PathLike[str]) -> str:
    """The path the user gave for an internal one: a run's hidden staging or set-aside folder
    (``.NAME.staging-XXXX``, ``.NAME.old-XXXX``) or an atomic write's temporary file (``.NAME.XXXX.tmp``)
    becomes ``NAME`` in the same place."""
    import re

    from .errors import path_like

    text = os.fspath(path_like("filename", filename))
    text = re.sub(r"(^|/)\.([^/]+?)\.(?:staging|old)-[^/]+", r"\1\2", text)
    return re.sub(r"(^|/)\.([^/]+?)\.[^/.]+\.tmp$", r"\1\2", text)


# --------------------------------------------------------------------------- run folders

#: Name of the file that binds a run folder: versions, seed and the SHA-256 of every file.
MANIFEST = "manifest.json"
_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


def _exchange(a: Path, b: Path) -> bool:
    """Swap two directory entries atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False if unsupported."""
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    rc = fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    if rc == 0:
        return True
    err = ctypes.get_errno()
    import errno

    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def sha256_of(path: Path) -> str:
    """Hexadecimal SHA-256 of the file at ``path``, read in 1 MiB blocks."""
    from .errors import path_like

    path = path_like("path", path)
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def check_folder_path(final: str | os.PathLike[str]) -> Path:
    """``final`` as a :class:`~pathlib.Path` when it can be (or become) an output folder, else
    :class:`~vtol_impedance.errors.InputError` naming what is in the way (:func:`explain_path`). Cheap:
    commands call it before any work."""
    from .errors import InputError, path_like

    final = path_like("final", final)
    why = explain_path(final, "folder")
    if why:
        raise InputError(f"cannot use {final} as the output folder: {why}; choose another --out")
    if is_recording(final):
        raise InputError(
            f"output folder {final} holds a live flight's recording (flight.tlog, written by `vtol-impedance "
            f"live`), which no command can make again; choose another --out (or move it away yourself)"
        )
    return final


def is_recording(folder: Path) -> bool:
    """Whether ``folder`` is a run folder that ``live`` wrote (its manifest says so, or, for folders written
    before manifests named their command, lists a ``flight.tlog``): a flight's recording, never replaced."""
    import json

    from .errors import path_like

    folder = path_like("folder", folder)
    try:
        manifest = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    if not isinstance(manifest, dict):
        return False
    files = manifest.get("files")
    return manifest.get("command") == "live" or (isinstance(files, dict) and "flight.tlog" in files)


def check_output_folder(final: Path, swapped: bool = True) -> Path:
    """Refuse, before any work, an output folder that cannot hold a run: a path through or onto a regular
    file, a mount point when the folder is ``swapped`` as a whole, or an existing folder that is not a run
    of this tool as it wrote it (no ``manifest.json`` of this tool, or files it does not list)."""
    from .errors import path_like

    final = path_like("final", final)
    from .errors import InputError

    final = check_folder_path(final)
    for parent in [final, *final.parents]:
        if parent.exists() and not parent.is_dir():
            where = "is" if parent == final else f"has {parent} in its path, which is"
            raise InputError(f"output folder {final} {where} a file (or a device), not a folder; choose another --out")
    mounted = final.exists() and (
        os.path.ismount(final) or final.stat().st_dev != final.absolute().parent.stat().st_dev
    )
    if swapped and mounted:
        inside = (
            "a new folder inside it"
            if final.absolute() == Path("/")
            else f"a folder inside it, e.g. --out {final / 'run'}"
        )
        raise InputError(
            f"output folder {final} is a mount point (a volume, a USB stick): a run replaces its folder as a "
            f"whole, which a mount point cannot be; give {inside}"
        )
    if final.exists() and any(final.iterdir()):
        if not (final / MANIFEST).exists():
            why = f"already holds files that no vtol-impedance run wrote (no {MANIFEST})"
        else:
            try:
                listed = _read_manifest(final)["files"]
                extra = sorted(_files_in(final) - set(listed))
                why = f"holds files its run did not write: {extra[:5]}" if extra else ""
            except InputError as exc:
                why = f"is not a vtol-impedance run folder ({exc})"
        if why:
            raise InputError(
                f"output folder {final} {why}; a run replaces its whole folder, so choose an empty or new --out"
            )
    return final


def _files_in(folder: Path) -> set[str]:
    """Every file under ``folder`` but its manifest, as paths relative to it."""
    return {str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()} - {MANIFEST}


def _read_manifest(folder: Path, tools: tuple[str, ...] = ("vtol-impedance",)) -> dict[str, Any]:
    """The manifest of a folder one of ``tools`` wrote (a run's; a sweep's is ``"vtol-impedance sweep"``),
    or :class:`~vtol_impedance.errors.InputError`."""
    import json

    from .errors import InputError

    try:
        manifest = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{folder} has no readable {MANIFEST}: {exc}") from None
    if (
        not isinstance(manifest, dict)
        or manifest.get("tool") not in tools
        or not isinstance(manifest.get("files"), dict)
    ):
        raise InputError(f"{folder / MANIFEST} was not written by vtol-impedance (no tool and files entries)")
    return manifest


class FolderLock:
    """An exclusive lock on an output folder (``flock`` on a hidden file beside it), taken at once or
    refused: a second run into the same folder fails with a clear error instead of mixing files."""

    def __init__(self, folder: Path) -> None:
        import fcntl

        from .errors import InputError, path_like

        folder = path_like("folder", folder)

        folder = Path(folder).absolute()
        self.path = folder.parent / f".{folder.name}.lock"
        try:
            folder.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.path, "a+")  # noqa: SIM115 (held until close)
        except OSError as exc:
            raise InputError(f"cannot create the output folder {folder}: {exc.strerror}") from None
        try:
            fcntl.flock(self._fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            # the holder before us removes its file on closing: a lock on a file no longer at the path is
            # no lock (another run may hold the new one)
            if os.stat(self.path).st_ino != os.fstat(self._fh.fileno()).st_ino:
                raise OSError
        except OSError:
            self._fh.close()
            raise InputError(
                f"another run is writing to {folder} right now; wait for it to finish or choose another --out"
            ) from None

    def close(self) -> None:
        """Release the lock and remove its file (removed while still held: no one can take it in between)."""
        if not self._fh.closed:
            with contextlib.suppress(OSError):
                os.unlink(self.path)
        self._fh.close()


class RunFolder:
    """All files of one run, bound together and swapped in at once.

    Files are written into a fresh hidden staging folder beside ``final``; :meth:`commit` adds a
    ``manifest.json`` (config hash, seed, versions, the SHA-256 of every file) and then exchanges the
    staging folder with ``final`` in one atomic ``renameat2(RENAME_EXCHANGE)`` (Linux), so whatever instant
    the process dies, ``final`` holds either the previous complete run or the new one. Elsewhere, or on a
    file system without the exchange, the old folder is renamed aside first and put back on the next run
    if the process died in between. A lock file beside the folder makes a second concurrent run into the
    same folder fail at once with a clear error; stale staging folders of killed runs are removed.
    """

    def __init__(self, final: str | os.PathLike[str], command: str = "run") -> None:
        from .errors import path_like

        self.command = command  # recorded in the manifest: a live recording is never replaced
        self.final = check_output_folder(path_like("final", final)).absolute()
        parent = self.final.parent
        self._lock = FolderLock(self.final)
        self._recover()
        self.staging = Path(tempfile.mkdtemp(prefix=f".{self.final.name}.staging-", dir=parent))
        os.chmod(self.staging, _default_dir_mode())
        self.done = False

    def _recover(self) -> None:
        import shutil

        parent, name = self.final.parent, self.final.name
        olds = sorted(parent.glob(f".{name}.old-*"))
        whole = [p for p in olds if (p / MANIFEST).is_file()]  # not a half-removed leftover
        if whole and not self.final.exists():  # died between the two renames of the fallback: put it back
            keep = max(whole, key=lambda p: p.stat().st_ctime_ns)  # the one renamed aside last
            os.rename(keep, self.final)
            olds = [p for p in olds if p != keep]
        for stale in [*olds, *parent.glob(f".{name}.staging-*")]:
            shutil.rmtree(stale, ignore_errors=True)

    def path(self, name: str) -> Path:
        return self.staging / name

    def commit(self, config: dict[str, Any], seed: Any = None) -> Path:
        """Write the manifest and swap the new run in; returns the final folder."""
        import hashlib
        import json
        import shutil
        import sys

        from . import __version__

        files = sorted(p for p in self.staging.rglob("*") if p.is_file())
        cfg_text = json.dumps(config, sort_keys=True, default=str)
        manifest = {
            "tool": "vtol-impedance",
            "command": self.command,
            "version": __version__,
            "python": sys.version.split()[0],
            "versions": _versions(),
            "seed": seed,
            "config_sha256": hashlib.sha256(cfg_text.encode()).hexdigest(),
            "files": {
                str(p.relative_to(self.staging)): {"sha256": sha256_of(p), "bytes": p.stat().st_size} for p in files
            },
        }
        write_text(self.staging / MANIFEST, json.dumps(manifest, indent=1))
        _fsync_dir(self.staging)
        if not self.final.exists():
            os.rename(self.staging, self.final)
        elif _exchange(self.staging, self.final):
            shutil.rmtree(self.staging, ignore_errors=True)  # it now holds the previous run
        else:
            old = Path(tempfile.mkdtemp(prefix=f".{self.final.name}.old-", dir=self.final.parent))
            os.rmdir(old)
            os.rename(self.final, old)
            os.rename(self.staging, self.final)
            shutil.rmtree(old, ignore_errors=True)
        _fsync_dir(self.final.parent)
        self.done = True
        return self.final

    def close(self) -> None:
        import shutil

        if not self.done:
            shutil.rmtree(self.staging, ignore_errors=True)
        self._lock.close()

    def __enter__(self) -> RunFolder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _versions() -> dict[str, str]:
    from importlib import metadata

    out = {}
    for pkg in ("numpy", "scipy", "numba", "matplotlib", "pyarrow", "pyulog", "mujoco"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def verify_run_folder(folder: str | os.PathLike[str]) -> dict[str, Any]:
    """Check that ``folder`` holds exactly the files its manifest lists, with their hashes; returns the
    manifest or raises :class:`~vtol_impedance.errors.InputError` naming what differs."""
    from .errors import path_like

    folder = path_like("folder", folder)
    from .errors import InputError

    folder = Path(folder)
    manifest = _read_manifest(folder, ("vtol-impedance", "vtol-impedance sweep"))
    listed = manifest["files"]
    present = _files_in(folder)
    if present != set(listed):
        raise InputError(
            f"{folder}: files differ from the manifest: extra {sorted(present - set(listed))}, "
            f"missing {sorted(set(listed) - present)}"
        )
    for name, meta in listed.items():
        if sha256_of(folder / name) != meta["sha256"]:
            raise InputError(f"{folder}: {name} does not match its hash in the manifest")
    return manifest
