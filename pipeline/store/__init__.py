"""The fleet store: every ingested test of every machine axis, read back by any command.

Two engines behind one interface (``base.Store``): a folder (``folder``: a Parquet dataset
partitioned by machine and axis with a SQLite manifest; the default, no server) and a
PostgreSQL database for a team (``postgres``). ``open_store`` picks the engine from the
location; ``content`` is the store's form of readings and the per-test digest that makes an
ingest idempotent; ``records`` the forecasts and compensations recorded for its axes (kept in
the tables of ``tables``). See ``docs/store.md``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

from features.readings.errors import InputError
from pipeline.store.base import MANIFEST

# URL schemes of a PostgreSQL store (libpq's two spellings and SQLAlchemy's driver form).
POSTGRES = ("postgresql", "postgres", "postgresql+psycopg")
_URL = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*://")


def is_url(location) -> bool:
    """``location`` is a URL (``scheme://...``), not a path."""
    return isinstance(location, str) and bool(_URL.match(location))


def is_store(location) -> bool:
    """``location`` names a store: a URL, or a folder holding the manifest (a folder that
    cannot be looked into counts too, so that opening it says why)."""
    if is_url(location):
        return True
    if not isinstance(location, (str, os.PathLike)):
        return False
    try:
        return (Path(location) / MANIFEST).is_file()
    except OSError:
        return os.path.isdir(location)


def redact(location) -> str:
    """``location`` as text without a password (``user:***@``, ``password=***``)."""
    text = str(location)
    if not is_url(text):
        return text
    try:
        parts = urlsplit(text)
    except ValueError:  # not a URL urllib can take apart: hide whatever may be a password
        return re.sub(r"^([^:/]+://[^:@/]*):[^@]*@", r"\1:***@", text)
    netloc = parts.netloc
    if parts.password is not None:
        user, _, host = netloc.rpartition("@")
        netloc = f"{user.partition(':')[0]}:***@{host}"
    query = re.sub(r"(?i)(^|&)(password)=[^&]*", r"\1\2=***", parts.query)
    return urlunsplit((parts.scheme, netloc, parts.path, query, parts.fragment))


def open_store(location, *, write: bool = False, parameter: str | None = None):
    """The store at ``location``.

    Parameters
    ----------
    location : str or path-like
        A store folder (for writing also a new or empty folder) or a ``postgresql://`` URL.
    write : bool
        Open for ``add``: checks that this user may write.
    parameter : str, optional
        The Python parameter that named the location, for errors.

    Raises
    ------
    InputError
        A file, an unreadable or foreign folder, a URL of another engine or one that cannot
        be opened, a store of a newer format, no write permission (``write``): one line that
        never shows the password.
    """
    if is_url(location):
        return _postgres(location, write, parameter)
    from pipeline.store.folder import FolderStore

    return FolderStore(location, write=write, parameter=parameter)


def _postgres(url: str, write: bool, parameter: str | None):
    scheme = url.split("://", 1)[0].lower()
    if scheme not in POSTGRES:
        raise InputError(f"cannot open a store at a {scheme}:// URL; expected a store folder "
                         "or a postgresql:// URL", file=redact(url), parameter=parameter)
    from pipeline.store.postgres import PostgresStore

    try:
        parts = urlsplit(url)
        password, _ = parts.password, parts.port  # the port is parsed (and checked) lazily
    except ValueError as err:
        raise InputError(f"is not a valid URL ({err}); expected postgresql://USER@HOST[:PORT]/"
                         "DATABASE (an IPv6 host in brackets: [::1])", file=redact(url),
                         parameter=parameter) from None
    return PostgresStore(url, redact(url), password, write=write, parameter=parameter)
