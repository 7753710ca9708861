"""A local file as a command's stdin, sent as base64 lines while it is read
(so a large archive never sits whole in memory)."""

from __future__ import annotations

import base64


class FileStdin(list):
    """The file at ``path`` as base64 lines.  A list because pyinfra's
    write_stdin iterates lists; read afresh each time (pyinfra resends stdin
    when sudo asks for a password)."""

    CHUNK = 57 * 1024  # a multiple of 57 bytes: whole 76-character base64 lines

    def __init__(self, path: str):
        super().__init__()
        self.path = path

    def __bool__(self) -> bool:
        return True

    def __iter__(self):
        with open(self.path, "rb") as source:
            while chunk := source.read(self.CHUNK):
                yield base64.encodebytes(chunk).decode()
