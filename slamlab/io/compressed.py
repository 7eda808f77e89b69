"""Whole text files that may be gzip, bzip2 or xz compressed (CARMEN logs, relations files)."""

from __future__ import annotations

import bz2
import gzip
import lzma
import zlib
from pathlib import Path

from slamlab.errors import DataError

_MAGIC = {b"\x1f\x8b": "gzip", b"BZh": "bzip2", b"\xfd7zXZ\x00": "xz"}
_SUFFIX_KIND = {".gz": "gzip", ".bz2": "bzip2", ".xz": "xz"}
_OPENERS = {"gzip": gzip.open, "bzip2": bz2.open, "xz": lzma.open}


def _sniff(head: bytes) -> str:
    for magic, kind in _MAGIC.items():
        if head.startswith(magic):
            return kind
    return "plain"


def read_text(path: Path) -> str:
    """The whole file as text, decompressed by magic bytes (the suffix must agree).

    Errors name the file; a truncated or corrupt stream also names the first line it could
    not read. Decoded as latin-1, which never fails: stray bytes surface later as "not a
    number" errors of the parser, with their line."""
    if not path.exists():
        raise DataError(path, "file not found")
    if not path.is_file():
        raise DataError(path, "not a regular file")
    with path.open("rb") as f:
        head = f.read(6)
    kind = _sniff(head)
    named = _SUFFIX_KIND.get(path.suffix.lower(), "plain")
    if named != "plain" and kind != named:
        raise DataError(path, f"named {path.suffix} but is not {named} data (starts with {head!r})")
    if kind == "plain":
        data = path.read_bytes()
    else:
        chunks: list[bytes] = []
        lines_done = 0
        try:
            with _OPENERS[kind](path, "rb") as f:
                while chunk := f.read(1 << 22):
                    chunks.append(chunk)
                    lines_done += chunk.count(b"\n")
        except (EOFError, OSError, zlib.error, lzma.LZMAError) as exc:
            raise DataError(
                path,
                f"{kind} stream is truncated or corrupt ({exc}); "
                f"{lines_done} complete lines were read before it broke",
                record=f"line {lines_done + 1}",
            ) from None
        data = b"".join(chunks)
        del chunks  # the chunks, the joined bytes and the text at once were three copies (Intel: 49 MB)
    return data.decode("latin-1")
