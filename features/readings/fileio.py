"""Atomic output: a user error half-way through never leaves a half-written file behind.

Every output is written to a temporary file beside its destination and renamed into place
only on success. Temporary files are named ``.<name>.<random>.backlash-tmp-<pid><suffix>``:

- on a Python exception they are removed by ``atomic_path`` itself;
- on SIGTERM a handler removes every temporary file the process still has open, then the
  process exits with 143 (128 + SIGTERM); SIGTERM is held back while a file is created and
  registered, so no file exists that the handler does not know;
- a SIGKILL cannot be caught, so the next run that writes into the same folder (or names it
  with ``--out``) removes the temporary files of processes that are no longer alive.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import secrets
import shutil
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from features.readings.errors import InputError

TEMP_MARK = ".backlash-tmp-"
_TEMP_NAME = re.compile(r"^\..+\.backlash-tmp-(\d+)(\.[^.]*)?$")
# Errors the user can fix (full disk, read-only or forbidden place): one line, not a traceback.
_USER_ERRNOS = {errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT,
                errno.ENOTDIR, errno.EISDIR, errno.EEXIST, errno.ENAMETOOLONG}
_STARTED = time.time()
_UMASK = os.umask(0o022)
os.umask(_UMASK)
_open_temps: set[str] = set()
_swept: set[str] = set()
# re-entrant: the SIGTERM handler runs in the main thread, which may hold it at that moment
_lock = threading.RLock()
_handler: dict = {}


def _new_temp(beside: Path, suffix: str, make) -> str:
    """A new hidden temporary name beside ``beside``, made by ``make(name)``
    (``_create_file`` or ``os.mkdir``) and known to the SIGTERM handler from before it exists.

    Registering first closes the window in which a SIGTERM finds a file it does not know:
    Python runs the handler in the main thread at its next instruction, and the kernel hands
    the signal to whichever thread does not block it, so masking it in this thread cannot
    hold it back. A name that exists already (another run's) is never registered.
    """
    while True:
        tmp = str(beside.parent / f".{beside.name}.{secrets.token_hex(4)}{TEMP_MARK}"
                  f"{os.getpid()}{suffix}")
        if os.path.lexists(tmp):
            continue
        with _lock:
            _open_temps.add(tmp)
        try:
            make(tmp)
            return tmp
        except BaseException as err:
            with _lock:
                _open_temps.discard(tmp)
            if isinstance(err, FileExistsError):
                continue
            if isinstance(err, OSError):
                raise _user_error(err, beside) from None
            raise


def _create_file(name: str) -> None:
    os.close(os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path``; rename it into place only on success."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a folder; expected a file name", file=path)
    _make_folder(path.parent)
    sweep_orphans(path.parent)
    _install_sigterm_handler()
    tmp = _new_temp(path, path.suffix, _create_file)
    try:
        yield Path(tmp)
        if "terminating" in _handler:  # SIGTERM came where its SystemExit was swallowed
            raise SystemExit(128 + signal.SIGTERM)
        os.chmod(tmp, 0o666 & ~_UMASK)  # made 0600; outputs follow the umask
        os.replace(tmp, path)
    except OSError as err:
        if err.errno in _USER_ERRNOS:
            raise _user_error(err, path) from None
        raise
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        with _lock:
            _open_temps.discard(tmp)


def temp_folder(beside: str | os.PathLike) -> Path:
    """A new hidden temporary folder next to ``beside`` for outputs written together and
    renamed into place at the end; removed on SIGTERM and swept after a SIGKILL like the
    temporary files of ``atomic_path``. The caller removes it when done."""
    beside = Path(beside)
    _make_folder(beside.parent)
    sweep_orphans(beside.parent)
    _install_sigterm_handler()
    return Path(_new_temp(beside, "", lambda name: os.mkdir(name, 0o700)))


def write_files(out: str | os.PathLike, contents: dict[str, bytes]) -> dict[str, Path]:
    """Files (name -> bytes) into folder ``out`` together: written into a ``temp_folder``
    beside it, then each renamed into place (an error or a kill leaves none of them half
    written). Returns the paths by name."""
    out = Path(out)
    tmp = temp_folder(out)
    try:
        for name, content in contents.items():
            (tmp / name).write_bytes(content)
        out.mkdir(exist_ok=True)
        for name in contents:
            os.replace(tmp / name, out / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        with _lock:
            _open_temps.discard(str(tmp))
    return {name: out / name for name in contents}


class MemoryFolder:
    """A folder of files made in memory (name -> bytes), for ``write_files`` to write
    together: files that must be read back and checked before any reaches the disk (the
    compensation files) are made here, and written once.

    ``folder / name`` is a ``MemoryFile``; ``contents`` holds the bytes by name, in the order
    they were made.
    """

    def __init__(self):
        self.contents: dict[str, bytes] = {}

    def __truediv__(self, name: str) -> MemoryFile:
        return MemoryFile(self, str(name))


@dataclass(frozen=True)
class MemoryFile:
    """A file of a ``MemoryFolder``: the few ``pathlib.Path`` methods writers and readers use
    (``name``, ``stem``, ``write_text``, ``write_bytes``, ``read_bytes``)."""

    folder: MemoryFolder
    name: str

    @property
    def stem(self) -> str:
        return Path(self.name).stem

    def write_bytes(self, data: bytes) -> None:
        self.folder.contents[self.name] = bytes(data)

    def write_text(self, text: str, encoding: str = "utf-8") -> None:
        self.write_bytes(text.encode(encoding))

    def read_bytes(self) -> bytes:
        try:
            return self.folder.contents[self.name]
        except KeyError:
            raise FileNotFoundError(2, "No such file", self.name) from None

    def __str__(self) -> str:
        return self.name


def check_output(path: str | os.PathLike, kind: str, option: str = "--out") -> Path | None:
    """Refuse an output path that cannot be written, before any work is done.

    ``kind`` is ``"file"`` or ``"folder"``. Refused: a folder where a file is expected and
    the reverse, a file in the way of a folder to create, a place without write permission.
    Orphaned temporary files of killed runs in the output folder are removed. Returns the
    outermost folder that does not exist yet (the run will create it), or None.
    """
    path = Path(path)
    if kind == "file" and path.is_dir():
        raise InputError(f"{option} is a folder; expected a file name", file=path)
    if kind == "folder" and path.exists() and not path.is_dir():
        raise InputError(f"{option} is a file; expected a folder", file=path)
    folder = path if kind == "folder" else path.parent
    missing = None
    existing = folder.absolute()
    while not existing.exists():
        missing, existing = existing, existing.parent
    if not existing.is_dir():
        raise InputError(f"{option}: {existing} is a file; expected a folder on the way",
                         file=path)
    if not os.access(existing, os.W_OK | os.X_OK):
        raise InputError(f"{option}: cannot write into {existing} (permission denied)",
                         file=path)
    if missing is None:
        sweep_orphans(folder)
    return missing


def sweep_orphans(folder: str | os.PathLike) -> list[Path]:
    """Remove temporary files left in ``folder`` by killed processes; return what was removed.

    A temporary file is an orphan when its writer (the pid in its name) is no longer alive
    and it is older than this process, so files of concurrent runs are never touched.
    """
    removed = []
    with _lock:
        key = os.path.abspath(folder)
        if key in _swept:
            return removed
        _swept.add(key)
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        match = _TEMP_NAME.match(entry.name)
        if not match or int(match[1]) == os.getpid() or _alive(int(match[1])):
            continue
        with contextlib.suppress(OSError):
            if entry.stat(follow_symlinks=False).st_mtime < _STARTED:
                _remove(entry.path)
                removed.append(Path(entry.path))
    return removed


def _remove(path: str) -> None:
    if os.path.isdir(path) and not os.path.islink(path):
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, owned by someone else
        return True
    return True


def _make_folder(folder: Path, option: str | None = None) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise InputError(f"{option + ': ' if option else ''}cannot create folder: a file is "
                         "in the way", file=folder) from None
    except OSError as err:  # /proc, a read-only mount, no permission: the place is wrong
        raise InputError(f"{option + ': ' if option else ''}cannot create folder: "
                         f"{err.strerror}", file=folder) from None


def _user_error(err: OSError, path: Path) -> InputError:
    return InputError(f"cannot write file: {err.strerror}", file=path)


def _install_sigterm_handler() -> None:
    """Remove this process's temporary files on SIGTERM, then exit 143 (once per process)."""
    if "previous" in _handler or threading.current_thread() is not threading.main_thread():
        return
    _handler["previous"] = signal.getsignal(signal.SIGTERM)
    signal.signal(signal.SIGTERM, _on_sigterm)


def _on_sigterm(signum, frame) -> None:
    # The SystemExit below is lost when the signal lands in a finaliser or a C callback that
    # ignores exceptions; the flag keeps the write from being renamed into place anyway.
    _handler["terminating"] = True
    with _lock:
        temps = list(_open_temps)
    for tmp in temps:
        with contextlib.suppress(OSError):
            _remove(tmp)
    if callable(_handler["previous"]):
        _handler["previous"](signum, frame)
    # A second SIGTERM while unwinding ends the process at once.
    signal.signal(signal.SIGTERM, lambda *_: os._exit(128 + signal.SIGTERM))
    raise SystemExit(128 + signal.SIGTERM)


def write_text(path, text: str) -> Path | MemoryFile:
    """``text`` into file ``path`` (UTF-8), atomically; a ``MemoryFile`` keeps it in memory."""
    if isinstance(path, MemoryFile):
        path.write_text(text)
        return path
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def write_json(path, obj) -> Path:
    return write_text(path, json.dumps(obj, indent=2, default=_json_default) + "\n")


# Characters of JSON up to which stdout is indented for people to read; above it a fleet's
# output goes out compact, through the C encoder (indenting uses the pure-Python one, 10x slower).
INDENT_UP_TO = 100_000


def dumps(obj) -> str:
    """JSON for stdout: NaN becomes null, numpy scalars become plain numbers; indented unless
    it is long (``INDENT_UP_TO``)."""
    text = json.dumps(obj, default=_json_default, allow_nan=False)
    if len(text) > INDENT_UP_TO:
        return text
    return json.dumps(obj, indent=2, default=_json_default, allow_nan=False)


def _json_default(value):
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if hasattr(value, "isoformat"):
        return value.isoformat()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def clean_nan(obj):
    """Replace float NaN/inf with None recursively so output is strict JSON."""
    import math

    if isinstance(obj, dict):
        return {k: clean_nan(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean_nan(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if hasattr(obj, "item") and hasattr(obj, "dtype"):
        return clean_nan(obj.item())
    return obj


def read_toml(path, what: str = "file") -> dict:
    """A TOML file as a dict; an unreadable or invalid file is one ``InputError`` naming it."""
    import tomllib

    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"cannot read {what}: no such file", file=path) from None
    except (UnicodeDecodeError, IsADirectoryError) as err:
        raise InputError(f"cannot read {what}: {err}", file=path) from None
    except OSError as err:  # a symbolic-link loop, no permission, a device: one line
        reason = "symbolic link loop" if err.errno == errno.ELOOP else err.strerror
        raise InputError(f"cannot read {what}: {reason}", file=path) from None
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"invalid TOML: {err}", file=path) from None
