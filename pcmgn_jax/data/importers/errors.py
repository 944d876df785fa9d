"""The importers' error type and text-file reading (encoding sniffing)."""
from __future__ import annotations

from pathlib import Path


class InputFileError(ValueError):
    """Bad input file: a one-line message naming the file, the line / node / element / column and the fix."""


def read_text(path: Path) -> str:
    """A text file's contents: UTF-16 (BOM), UTF-8 (optional BOM) or cp1252, as ANSYS tools write them."""
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise InputFileError(f"{path}: cannot read: {err.strerror}") from None
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return raw.decode("utf-16")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("cp1252", errors="replace")
