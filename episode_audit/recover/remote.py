"""Recovery of a file in object storage, or into it: through a local temporary copy.

:func:`recover_remote` downloads a remote input, recovers it locally (the record walk needs
the whole file anyway) and uploads the finished output when ``out`` is a URL.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

from ..errors import ConfigurationError
from ..read.storage import RemoteFile, Source, as_source, download, exists, upload
from .result import RecoveryResult

__all__ = ["recover_remote"]


def recover_remote(
    path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    overwrite: bool,
    local: Callable[..., RecoveryResult],
    overwrite_option: str = "overwrite=True",
) -> RecoveryResult:
    """Recover ``path`` into ``out``, either a URL, with ``local`` (the local recovery).

    ``overwrite_option``: how the error for an existing ``out`` names ``overwrite``.
    """
    src, dst = as_source(path), as_source(out)
    if isinstance(src, RemoteFile) and isinstance(dst, RemoteFile) and src.url == dst.url:
        raise ConfigurationError(f"{dst}: is the input; recovery never replaces its input")
    if isinstance(dst, RemoteFile) and not overwrite and exists(dst):
        raise ConfigurationError(f"{dst}: exists; pass {overwrite_option} to replace it")
    with tempfile.TemporaryDirectory(prefix="episode-audit-recover-") as tmp:
        local_src: Source = src
        if isinstance(src, RemoteFile):
            local_src = Path(tmp) / (src.name or "input.mcap")
            download(src, local_src)
        local_dst = Path(tmp) / "recovered.mcap" if isinstance(dst, RemoteFile) else dst
        result = local(
            local_src,
            local_dst,
            overwrite=overwrite or isinstance(dst, RemoteFile),
            overwrite_option=overwrite_option,
        )
        if isinstance(dst, RemoteFile):
            upload(Path(local_dst), dst)
    return dataclasses.replace(result, source=src, output=dst)
