"""Evidence in object storage and at URLs (``s3://``, ``gs://``, ``az://``, ``http(s)://``).

:func:`is_url` tells a URL from a local path; :func:`remote_file` names a file through
``fsspec`` as a :class:`RemoteFile` (a ``str``: its URL, printed without secrets, that carries
its filesystem); :func:`open_source` opens a local path or a remote file for reading, remote
ones as seekable file objects that fetch byte ranges on demand (:data:`BLOCK_BYTES` a request
at least); :func:`list_remote` finds ``*.mcap`` files under a prefix; :func:`upload` copies a
finished local file to a URL. ``fsspec`` is imported only when a URL is met. Timeouts, retries
and credentials: ``docs/storage.md``.
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any
from urllib.parse import parse_qsl, urlsplit, urlunsplit

from ..errors import ConfigurationError, EvidenceError

__all__ = [
    "BLOCK_BYTES",
    "EDGE_BYTES",
    "CONNECT_TIMEOUT_S",
    "READ_TIMEOUT_S",
    "RETRIES",
    "RemoteFile",
    "Source",
    "as_output",
    "as_source",
    "download",
    "exists",
    "file_size",
    "is_url",
    "list_remote",
    "open_source",
    "remote_file",
    "shown_url",
    "upload",
]

CONNECT_TIMEOUT_S = 10.0
"""Seconds to wait for a connection to an object store or web server."""
READ_TIMEOUT_S = 60.0
"""Seconds to wait for data on an open connection."""
RETRIES = 3
"""Attempts at one request (S3: botocore's standard retry mode; s3fs's own loop runs once)."""
EDGE_BYTES = 1 << 18
"""Bytes at each end of a remote file read in one request and kept while it is open (256 KiB)."""
BLOCK_BYTES = 1 << 16
"""Bytes a ranged read fetches past what it asks for (64 KiB: the next small records)."""

_URL = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]*)://")
_SLASH_SHORT = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]*):/(?!/)")
"""``SCHEME:/`` not followed by a second ``/``: a URL one slash short (:func:`as_output`)."""
_FSSPEC_PROTOCOL = {"s3a": "s3", "gs": "gcs", "az": "abfs", "abfss": "abfs"}
_EXTRA = {"gcs": "gcs", "abfs": "azure", "https": "http"}
_EXTRAS = frozenset({"s3", "gcs", "azure", "http"})
"""The package's extras that install a filesystem (pyproject.toml)."""


def is_url(path: object) -> bool:
    """Whether ``path`` is a URL (``scheme://…``) other than ``file://``.

    >>> is_url("s3://bucket/runs/a.mcap"), is_url("runs/a.mcap"), is_url("file:///data/a.mcap")
    (True, False, False)
    """
    if isinstance(path, RemoteFile):
        return True
    match = _URL.match(path) if isinstance(path, str) else None
    return match is not None and match.group(1).lower() != "file"


def shown_url(url: str) -> str:
    """``url`` as printed: without a user name, password or query string (signatures, tokens).

    >>> shown_url("https://user:secret@host:8080/a.mcap?X-Amz-Signature=abc")
    'https://host:8080/a.mcap?…'
    """
    parts = urlsplit(url)
    netloc = parts.netloc.rpartition("@")[2]
    return urlunsplit((parts.scheme, netloc, parts.path, "…" if parts.query else "", ""))


class RemoteFile(str):
    """A file in object storage or at a URL: a ``str`` (its URL without secrets) with its fs.

    >>> f = RemoteFile("https://h/runs/a.mcap?X-Amz-Signature=f00", None, "https://h/runs/a.mcap?X")
    >>> f, f.name, f.stem, f.parent
    ('https://h/runs/a.mcap?…', 'a.mcap', 'a', 'https://h/runs')

    Attributes:
        url: The full URL, as given.
        fs: The ``fsspec`` filesystem that reads it.
        fs_path: Its path on ``fs``.
    """

    url: str
    fs: Any
    fs_path: str

    def __new__(cls, url: str, fs: Any, fs_path: str) -> RemoteFile:
        """The file at ``fs_path`` on ``fs``; ``url`` names it (shown without secrets)."""
        self = super().__new__(cls, shown_url(url))
        self.url, self.fs, self.fs_path = url, fs, fs_path
        return self

    def __reduce__(self) -> tuple[Any, ...]:  # pickled with its filesystem (worker processes)
        return (RemoteFile, (self.url, self.fs, self.fs_path))

    @property
    def name(self) -> str:
        """The last part of its path, as :attr:`pathlib.Path.name`."""
        path = urlsplit(self.fs_path).path if _URL.match(self.fs_path) else self.fs_path
        return path.rstrip("/").rpartition("/")[2]

    @property
    def parent(self) -> str:
        """The URL of the prefix it is in (shown without secrets)."""
        return shown_url(self.url).partition("?")[0].rpartition("/")[0]

    @property
    def stem(self) -> str:
        """:attr:`name` without its suffix, as :attr:`pathlib.Path.stem`."""
        return Path(self.name).stem


Source = Path | RemoteFile
"""An evidence file: a local path, or a :class:`RemoteFile`."""


def _fsspec() -> Any:
    try:
        import fsspec  # type: ignore[import-untyped]
    except ImportError:
        raise ConfigurationError(
            "reading URLs needs fsspec: pip install 'episode-audit[s3]' (or [gcs], [azure])"
        ) from None
    return fsspec


def _default_options(protocol: str) -> dict[str, Any]:
    """Timeouts and bounded retries for the protocols whose options are known here."""
    if protocol == "s3":
        return {
            "config_kwargs": {
                "connect_timeout": CONNECT_TIMEOUT_S,
                "read_timeout": READ_TIMEOUT_S,
                "retries": {"max_attempts": RETRIES, "mode": "standard"},
            },
        }
    if protocol in ("http", "https"):
        try:
            import aiohttp
        except ImportError:
            return {}
        timeout = aiohttp.ClientTimeout(
            total=None, connect=CONNECT_TIMEOUT_S, sock_read=READ_TIMEOUT_S
        )
        return {"client_kwargs": {"timeout": timeout}}
    return {}


def remote_file(
    url: str, *, filesystem: Any = None, storage_options: Mapping[str, Any] | None = None
) -> RemoteFile:
    """The file at ``url``, read through ``filesystem`` or one ``fsspec`` makes for it.

    ``storage_options`` go to that filesystem (credentials, ``endpoint_url`` …) over the
    defaults here (:data:`CONNECT_TIMEOUT_S`, :data:`READ_TIMEOUT_S`, :data:`RETRIES`).
    Raises :class:`~episode_audit.errors.ConfigurationError` when no filesystem reads the
    URL's scheme (naming the package to install).
    """
    if isinstance(url, RemoteFile) and filesystem is None and not storage_options:
        return url
    url = url.url if isinstance(url, RemoteFile) else url
    if filesystem is not None and not _URL.match(url):  # a path on the filesystem given
        return RemoteFile(filesystem.unstrip_protocol(url), filesystem, url)
    match = _URL.match(url)
    scheme = match.group(1).lower() if match else ""
    protocol = _FSSPEC_PROTOCOL.get(scheme, scheme)
    fsspec = _fsspec()
    if filesystem is None:
        options = {**_default_options(protocol), **(storage_options or {})}
        try:
            with _half_made_quiet():
                filesystem = fsspec.filesystem(protocol, **options)
        except ImportError:
            extra = _EXTRA.get(protocol, protocol)
            install = (
                f"pip install 'episode-audit[{extra}]'"
                if extra in _EXTRAS
                else f"install the fsspec filesystem for {scheme}://"
            )
            raise ConfigurationError(
                f"{shown_url(url)}: reading {scheme}:// URLs needs an fsspec filesystem that is "
                f"not installed: {install}"
            ) from None
        except Exception as exc:  # (ftp:// without a host: a TypeError; hdfs:// without a JVM)
            why = _without_secrets(" ".join(str(exc).split())[:200], url)
            raise ConfigurationError(
                f"{shown_url(url)}: cannot read {scheme}:// URLs ({type(exc).__name__}: {why}); "
                "evidence is read from s3://, gs://, az:// and http(s):// (docs/storage.md), "
                "or copy the file here"
            ) from None
        if protocol == "s3":
            filesystem.retries = 1  # s3fs's own loop (a class attribute, 5) around botocore's
    path = url if protocol in ("http", "https") else filesystem._strip_protocol(url)
    return RemoteFile(url, filesystem, path)


@contextmanager
def _half_made_quiet() -> Iterator[None]:
    """Construct a filesystem here; if that fails, its half-made object's complaints go unsaid.

    fsspec's FTP filesystem, freed half made, prints "Exception ignored ... __del__" with a
    traceback; what is raised while one is made that works is still printed.
    """
    hook = sys.unraisablehook
    held: list[Any] = []
    sys.unraisablehook = held.append
    try:
        yield
    except BaseException:
        held.clear()
        raise
    finally:
        sys.unraisablehook = hook
    for unraisable in held:
        hook(unraisable)


def as_source(
    path: str | os.PathLike[str],
    *,
    filesystem: Any = None,
    storage_options: Mapping[str, Any] | None = None,
) -> Source:
    """``path`` as a :data:`Source`: a :class:`RemoteFile` for a URL (or with ``filesystem``).

    See :func:`remote_file` for ``filesystem`` and ``storage_options``.

    >>> as_source("file:///data/run.mcap"), as_source("runs/a.mcap")
    (PosixPath('/data/run.mcap'), PosixPath('runs/a.mcap'))
    """
    if isinstance(path, RemoteFile) or filesystem is not None or is_url(path):
        return remote_file(os.fspath(path), filesystem=filesystem, storage_options=storage_options)
    if isinstance(path, str) and path.lower().startswith("file://"):
        return Path(urlsplit(path).path)
    return Path(path)


def as_output(
    path: str | os.PathLike[str],
    *,
    name: str = "--out",
    filesystem: Any = None,
    storage_options: Mapping[str, Any] | None = None,
) -> Source:
    """The output ``path`` names: a :class:`RemoteFile` for a URL, else a local path.

    A URL is as for inputs (:func:`is_url`: ``SCHEME://…``; ``file://`` is its local path);
    any other ``:`` is part of a local name (``exp-12:30``, ``mock:x``). ``SCHEME:/…``, one
    slash short of a URL, is refused rather than made a local folder ``SCHEME:``; the error,
    naming the argument ``name``, says how to write either. See :func:`remote_file` for
    ``filesystem`` and ``storage_options``.

    >>> as_output("exp-12:30"), as_output("file:///data/out")
    (PosixPath('exp-12:30'), PosixPath('/data/out'))
    >>> as_output("s3:/bucket/out")
    Traceback (most recent call last):
    ...
    episode_audit.errors.ConfigurationError: --out s3:/bucket/out: a URL takes two slashes: \
s3://bucket/out; a local path: ./s3:/bucket/out
    """
    if is_url(path):
        return remote_file(os.fspath(path), filesystem=filesystem, storage_options=storage_options)
    text = os.fspath(path)
    short = _SLASH_SHORT.match(text)
    if short is not None:
        scheme, rest = short.group(1), text[short.end() :]
        root = "/" if scheme.lower() == "file" else ""  # (file:///data/out)
        raise ConfigurationError(
            f"{name} {text}: a URL takes two slashes: {scheme}://{root}{rest}; "
            f"a local path: ./{text}"
        )
    return as_source(text)


def _why(exc: BaseException) -> str:
    """One line on a storage failure: what went wrong, and what to do when it is known."""
    cause = exc.__cause__ or exc.__context__
    if isinstance(exc, FileNotFoundError) and cause is not None and _not_a_404(cause):
        return _why(cause)  # (fsspec's HTTP filesystem says "not found" for any failure)
    name = type(exc).__name__
    text = " ".join(str(exc).split())[:200]
    if isinstance(exc, FileNotFoundError):
        return "no such file, bucket or prefix"
    status = getattr(exc, "status", None)
    if status in (401, 403):
        return f"access denied (HTTP {status}); check the URL's credentials or signature"
    if isinstance(exc, PermissionError) or "AccessDenied" in text or "Forbidden" in text:
        return f"access denied ({text}); check the credentials and their permissions"
    if name == "NoCredentialsError" or "Unable to locate credentials" in text:
        return (
            "no credentials found: set them as the storage's own tools expect (environment "
            "variables, a profile, an instance role; docs/storage.md)"
        )
    if isinstance(exc, TimeoutError) or "timeout" in name.lower() or "timed out" in text:
        return f"timed out ({name}); is the endpoint reachable?"
    if "support range requests" in text:  # (fsspec's advice is to open it as a stream)
        return (
            "the HTTP server does not answer Range requests, which reading needs: serve the "
            "file from one that does (nginx, S3, any object store), or download it"
        )
    if "connect" in name.lower() or "connect" in text.lower():
        return f"cannot connect ({text or name}); is the endpoint reachable?"
    return f"{name}: {text}" if text else name


def _not_a_404(cause: BaseException) -> bool:
    """Whether ``cause`` of a ``FileNotFoundError`` is access denied or no connection.

    fsspec's HTTP filesystem raises ``FileNotFoundError`` from either.
    """
    name = type(cause).__name__.lower()
    return (
        getattr(cause, "status", None) in (401, 403)
        or isinstance(cause, (ConnectionError, TimeoutError))
        or "connect" in name
        or "timeout" in name
    )


@contextmanager
def _storage_errors(path: RemoteFile, what: str, error: type[Exception]) -> Iterator[None]:
    """Any failure of the storage client inside: ``error`` with one line naming ``path``."""
    try:
        yield
    except (EvidenceError, ConfigurationError):
        raise
    except Exception as exc:
        why = _without_secrets(_why(exc), path.url)
        if error is ConfigurationError:
            raise ConfigurationError(f"{path}: {what}: {why}") from None
        raise EvidenceError(path, f"{what}: {why}") from None


def _without_secrets(text: str, url: str) -> str:
    """``text`` (a storage client's message) without the secrets ``url`` carries.

    A client may quote what it was given: the credentials before ``@`` (botocore's "Invalid
    bucket name "user:pass@bkt"") or the query (a signature); docs/security.md.

    >>> _without_secrets('Invalid bucket name "u:pw12@b"', "s3://u:pw12@b/k?sig=abcd")
    'Invalid bucket name "…b"'
    """
    parts = urlsplit(url)
    userinfo = parts.netloc.rpartition("@")[0]
    secrets = [f"{userinfo}@", userinfo, parts.password or "", parts.query]
    secrets += [value for _, value in parse_qsl(parts.query)]
    for secret in sorted(filter(None, secrets), key=len, reverse=True):
        if len(secret) >= 4 or secret.endswith("@"):
            text = text.replace(secret, "…")
    return text


def list_remote(path: RemoteFile) -> list[RemoteFile]:
    """``path`` if it is a file, else the ``*.mcap`` files under it (recursively, sorted).

    Raises :class:`~episode_audit.errors.ConfigurationError` for a URL that names nothing,
    a prefix without evidence files, or storage that cannot be reached or read.
    """
    fs = path.fs
    if path.url.endswith("/") and urlsplit(path.url).scheme.lower() in ("http", "https"):
        raise ConfigurationError(
            f"{path}: HTTP lists no folder: name each file's URL, or read the folder from "
            "s3://, gs:// or az://"
        )
    with _storage_errors(path, "cannot read", ConfigurationError):
        info = fs.info(path.fs_path)
        if info.get("type") != "directory":
            return [path]
        found = sorted(p for p in fs.find(path.fs_path) if p.endswith(".mcap"))
    if not found:
        raise ConfigurationError(f"{path}: no *.mcap files under this prefix")
    return [RemoteFile(fs.unstrip_protocol(p), fs, p) for p in found]


def first_bytes(files: list[RemoteFile], size: int) -> list[bytes | None]:
    """The first ``size`` bytes of each of ``files`` (one listing's: one filesystem), or ``None``.

    Read together (``cat_ranges``: concurrent requests on object storage). ``None`` for a file
    that could not be read; raises nothing: opening such a file says why.
    """
    if not files:
        return []
    try:
        got = files[0].fs.cat_ranges(
            [f.fs_path for f in files], [0] * len(files), [size] * len(files), on_error="return"
        )
    except Exception:  # (the storage client's own failure: read none)
        return [None] * len(files)
    return [g if isinstance(g, bytes) else None for g in got]


def open_source(path: Source, *, edges: bool = True) -> IO[bytes]:
    """``path`` opened for reading: a local file, or a remote one read by byte ranges.

    ``edges``: keep a remote file's first and last bytes (see :class:`_Guarded`), for opening
    it; a pass over its chunks does without. Raises
    :class:`~episode_audit.errors.EvidenceError` when it cannot be opened.
    """
    if isinstance(path, RemoteFile):
        with _storage_errors(path, "cannot open", EvidenceError):
            f: IO[bytes] = path.fs.open(
                path.fs_path, "rb", block_size=BLOCK_BYTES, cache_type="readahead"
            )
        return _Guarded(f, path, edges)  # type: ignore[return-value]
    try:
        return open(path, "rb")
    except OSError as exc:
        raise EvidenceError(path, f"cannot open: {exc.strerror}") from None


class _Guarded:
    """A remote file object whose read failures are :class:`EvidenceError` with one line.

    A small read in the first or last :data:`EDGE_BYTES` reads that whole edge in one request
    and keeps it (the header and run metadata; the footer, summary and run-end record), so
    that opening a file costs two requests; other reads are passed on.
    """

    def __init__(self, f: Any, path: RemoteFile, edges: bool = True) -> None:
        self._f, self._path, self._edges_kept = f, path, edges
        self.size: int = f.size
        self._pos = 0
        self._edges: list[tuple[int, bytes]] = []  # (offset, bytes) of the edges read

    def read(self, n: int = -1) -> bytes:
        pos = self._pos
        end = self.size if n is None or n < 0 else min(self.size, pos + n)
        if pos >= end:
            return b""
        kept = self._kept(pos, end)
        if kept is None:
            kept = self._fetch(pos, end - pos)
        self._pos = pos + len(kept)
        return kept

    def _kept(self, pos: int, end: int) -> bytes | None:
        """Bytes ``pos`` to ``end`` from an edge of the file, read first if need be."""
        for start, data in self._edges:
            if start <= pos and end <= start + len(data):
                return data[pos - start : end - start]
        if end - pos > BLOCK_BYTES or not self._edges_kept:  # a chunk: read as asked
            return None
        if end <= EDGE_BYTES:
            start = 0
        elif pos >= self.size - EDGE_BYTES:
            start = max(0, self.size - EDGE_BYTES)
        else:
            return None
        data = self._fetch(start, min(self.size, start + EDGE_BYTES) - start)
        self._edges.append((start, data))
        return data[pos - start : end - start]

    def _fetch(self, pos: int, n: int) -> bytes:
        with _storage_errors(self._path, "cannot read", EvidenceError):
            self._f.seek(pos)
            data: bytes = self._f.read(n)
        return data

    def seek(self, offset: int, whence: int = 0) -> int:
        base = {0: 0, 1: self._pos, 2: self.size}[whence]
        if base + offset < 0:
            raise ValueError(f"negative seek position {base + offset}")
        self._pos = base + offset
        return self._pos

    def tell(self) -> int:
        return self._pos

    def seekable(self) -> bool:
        return True

    def readable(self) -> bool:
        return True

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> _Guarded:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def file_size(f: IO[bytes]) -> int:
    """The size of an open file: a local one's ``fstat``, a remote one's listed size."""
    size = getattr(f, "size", None)
    if isinstance(size, int):
        return size
    return os.fstat(f.fileno()).st_size


def download(url: RemoteFile, local: Path) -> None:
    """Copy the remote file ``url`` to the local path ``local``.

    Raises :class:`~episode_audit.errors.EvidenceError` when it cannot be read.
    """
    with _storage_errors(url, "cannot read", EvidenceError):
        url.fs.get_file(url.fs_path, os.fspath(local))


def exists(url: RemoteFile) -> bool:
    """Whether something is at ``url``.

    Raises :class:`~episode_audit.errors.ConfigurationError` when the storage cannot say.
    """
    with _storage_errors(url, "cannot read", ConfigurationError):
        return bool(url.fs.exists(url.fs_path))
    raise AssertionError  # pragma: no cover - (for type checkers: the block returns or raises)


def upload(local: Path, url: RemoteFile) -> None:
    """Copy the finished local file ``local`` to ``url``.

    Raises :class:`~episode_audit.errors.ConfigurationError` when the storage refuses it.
    """
    with _storage_errors(url, "cannot write", ConfigurationError):
        url.fs.put_file(os.fspath(local), url.fs_path)
