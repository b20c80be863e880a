"""One file field of a ``multipart/form-data`` body, read as the body arrives (sans-I/O: chunks of
the body in, the field's file name and data out), so an upload goes to disk a chunk at a time and is
never held in memory whole. Other fields are skipped."""

from __future__ import annotations

from python_multipart.exceptions import FormParserError
from python_multipart.multipart import MultipartParser, parse_options_header


class MultipartRefused(ValueError):
    """A body that is no multipart form with exactly one file in the expected field."""


class FileField:
    """The file sent in form field ``field`` of a body whose ``Content-Type`` is ``content_type``.

    :meth:`feed` each chunk of the body: it returns the field's data in that chunk, and
    :attr:`filename` is set once the field's headers have arrived. :meth:`finish` at the end."""

    def __init__(self, content_type: str, field: str) -> None:
        kind, options = parse_options_header(content_type)
        if kind != b"multipart/form-data" or not options.get(b"boundary"):
            raise MultipartRefused(f"send a multipart/form-data body with the file in field {field!r}")
        self.field = field
        self.filename: str | None = None
        self._ended = False
        self._in_field = False
        self._header_name = bytearray()
        self._header_value = bytearray()
        self._disposition = b""
        self._data: list[bytes] = []
        self._parser = MultipartParser(options[b"boundary"], {
            "on_part_begin": self._part_begin,
            "on_header_field": lambda data, start, end: self._header_name.extend(data[start:end]),
            "on_header_value": lambda data, start, end: self._header_value.extend(data[start:end]),
            "on_header_end": self._header_end,
            "on_headers_finished": self._headers_finished,
            "on_part_data": self._part_data,
            "on_part_end": self._part_end,
        })

    def feed(self, chunk: bytes) -> list[bytes]:
        """The file's bytes in ``chunk`` (possibly none); raises :class:`MultipartRefused`."""
        try:
            self._parser.write(chunk)
        except FormParserError as exc:
            raise MultipartRefused(f"malformed multipart body ({exc})") from None
        data, self._data = self._data, []
        return data

    def finish(self) -> None:
        """The body is complete; raises :class:`MultipartRefused` when it held no whole file field."""
        try:
            self._parser.finalize()
        except FormParserError as exc:
            raise MultipartRefused(f"malformed multipart body ({exc})") from None
        if self.filename is None or not self._ended:
            raise MultipartRefused(f"no complete file in form field {self.field!r}")

    def _part_begin(self) -> None:
        self._disposition = b""

    def _header_end(self) -> None:
        if bytes(self._header_name).lower() == b"content-disposition":
            self._disposition = bytes(self._header_value)
        self._header_name.clear()
        self._header_value.clear()

    def _headers_finished(self) -> None:
        _, options = parse_options_header(self._disposition)
        self._in_field = options.get(b"name", b"").decode("utf-8", errors="replace") == self.field
        if not self._in_field:
            return
        if self.filename is not None:
            raise MultipartRefused(f"one file per upload: form field {self.field!r} came twice")
        if b"filename" not in options:
            raise MultipartRefused(f"form field {self.field!r} is no file (its part has no filename)")
        # Headers arrive as bytes, taken as Latin-1 by the parser; browsers send file names in UTF-8.
        try:
            self.filename = options[b"filename"].decode("utf-8")
        except UnicodeDecodeError:
            raise MultipartRefused("the file name is not UTF-8") from None

    def _part_data(self, data: bytes, start: int, end: int) -> None:
        if self._in_field:
            self._data.append(data[start:end])

    def _part_end(self) -> None:
        if self._in_field:
            self._ended = True
        self._in_field = False
