"""Receiving a scan upload: multipart parsed as it streams, the file written straight to disk.

Starlette's form parser would first spool the whole file to a temporary file and only then let
us check its size; here every chunk goes to the data directory's ``incoming/`` folder as it
arrives, the size limit is enforced while streaming (and from Content-Length before reading
anything), and the file name is reduced to a safe base name.
"""

from __future__ import annotations

import logging
import re
import unicodedata
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import BinaryIO

import anyio
from fastapi import Request
from python_multipart.exceptions import FormParserError
from python_multipart.multipart import MultipartParser, parse_options_header

from jointseg.exceptions import ConfigError, UnsupportedFormatError, UploadTooLarge
from jointseg.io import READ_EXTENSIONS
from server.storage import Storage

log = logging.getLogger(__name__)

#: Longest file name kept (bytes of UTF-8, as most file systems count).
MAX_FILENAME_BYTES = 255
#: Largest ``config`` form field.
MAX_CONFIG_BYTES = 1 << 20
#: Bytes collected before they are written to disk in a worker thread.
WRITE_BATCH = 1 << 20
FILE_FIELD = "file"
CONFIG_FIELD = "config"

#: The request body as OpenAPI describes it (the route reads the stream itself).
UPLOAD_OPENAPI = {
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "required": [FILE_FIELD],
                    "properties": {
                        FILE_FIELD: {
                            "type": "string",
                            "format": "binary",
                            "description": "The scan; its extension names the format ("
                            + ", ".join(READ_EXTENSIONS)
                            + ").",
                        },
                        CONFIG_FIELD: {
                            "type": "string",
                            "description": "Optional PipelineConfig as JSON, e.g. "
                            '{"network": {"name": "randlanet"}, "fusion": {"mode": "paper"}}',
                        },
                    },
                }
            }
        },
    }
}


@dataclass
class ReceivedUpload:
    """An upload on disk (temporary name) with the form's other field."""

    filename: str
    suffix: str
    path: Path
    size: int
    config: str | None = None


def safe_filename(raw: str) -> str:
    """The base name of a client's file name, without folders or control characters.

    Raises
    ------
    ConfigError
        For an empty name or one longer than :data:`MAX_FILENAME_BYTES`.
    """
    name = unicodedata.normalize("NFC", raw)
    name = PureWindowsPath(PurePosixPath(name.replace("\x00", "")).name).name
    name = re.sub(r"[\x00-\x1f\x7f]", "", name).strip().lstrip(".")
    if not name:
        raise ConfigError(f"upload file name {raw[:80]!r} has no usable base name")
    if len(name.encode()) > MAX_FILENAME_BYTES:
        raise ConfigError(
            f"upload file name is {len(name.encode())} bytes long; at most "
            f"{MAX_FILENAME_BYTES} allowed"
        )
    return name


def upload_suffix(filename: str) -> str:
    """The lower-case extension of ``filename`` when jointseg reads it.

    Raises
    ------
    UnsupportedFormatError
        Listing the extensions that are read.
    """
    suffix = Path(filename).suffix.lower()
    if suffix not in READ_EXTENSIONS:
        raise UnsupportedFormatError(
            f"{filename}: unsupported file extension {suffix or '(none)'!r}; supported: "
            f"{', '.join(READ_EXTENSIONS)}"
        )
    return suffix


@dataclass
class _Part:
    headers: dict[bytes, bytes] = field(default_factory=dict)
    name: str = ""
    filename: str | None = None


class _Receiver:
    """python-multipart callbacks: file bytes collected for writing, the config kept in memory."""

    def __init__(self, storage: Storage, max_bytes: int) -> None:
        self.storage = storage
        self.max_bytes = max_bytes
        self.part = _Part()
        self._field = b""
        self._value = b""
        self.file: BinaryIO | None = None
        self.upload: ReceivedUpload | None = None
        self.config: bytearray | None = None
        self.pending: list[bytes] = []
        self.size = 0

    def on_part_begin(self) -> None:
        self.part = _Part()

    def on_header_field(self, data: bytes, start: int, end: int) -> None:
        self._field += data[start:end]

    def on_header_value(self, data: bytes, start: int, end: int) -> None:
        self._value += data[start:end]

    def on_header_end(self) -> None:
        self.part.headers[self._field.lower()] = self._value
        self._field = self._value = b""

    def on_headers_finished(self) -> None:
        _, options = parse_options_header(self.part.headers.get(b"content-disposition", b""))
        if b"name" not in options:
            raise ConfigError("multipart part without a name in Content-Disposition")
        self.part.name = options[b"name"].decode("utf-8", "replace")
        if b"filename" in options:
            self.part.filename = options[b"filename"].decode("utf-8", "replace")
        if self.part.name == FILE_FIELD:
            self._open_file()
        elif self.part.name == CONFIG_FIELD:
            if self.config is not None:
                raise ConfigError("form field 'config' given twice")
            self.config = bytearray()
        else:
            raise ConfigError(
                f"unknown form field {self.part.name[:80]!r}; expected {FILE_FIELD!r} and "
                f"optionally {CONFIG_FIELD!r}"
            )

    def _open_file(self) -> None:
        if self.upload is not None:
            raise ConfigError("form field 'file' given twice; upload one scan per job")
        if self.part.filename is None:
            raise ConfigError("form field 'file' must be a file (with a file name)")
        filename = safe_filename(self.part.filename)
        suffix = upload_suffix(filename)
        path = self.storage.new_incoming(suffix)
        self.upload = ReceivedUpload(filename=filename, suffix=suffix, path=path, size=0)
        self.file = open(path, "wb")  # noqa: SIM115 - closed by receive_upload

    def on_part_data(self, data: bytes, start: int, end: int) -> None:
        if self.part.name == FILE_FIELD:
            self.size += end - start
            if self.size > self.max_bytes:
                raise UploadTooLarge(f"upload is larger than the limit of {self.max_bytes:,} bytes")
            self.pending.append(bytes(data[start:end]))
        elif self.config is not None:
            self.config += data[start:end]
            if len(self.config) > MAX_CONFIG_BYTES:
                raise UploadTooLarge(f"form field 'config' is larger than {MAX_CONFIG_BYTES} bytes")

    def on_part_end(self) -> None:
        pass

    def take_pending(self) -> bytes:
        data = b"".join(self.pending)
        self.pending.clear()
        return data


async def receive_upload(request: Request, storage: Storage, *, max_bytes: int) -> ReceivedUpload:
    """Stream a ``multipart/form-data`` request's scan to a temporary file in ``storage``.

    Returns
    -------
    ReceivedUpload
        The caller moves ``path`` into place (or deletes it).

    Raises
    ------
    UploadTooLarge
        When Content-Length or the streamed bytes exceed ``max_bytes`` (the partial file is
        removed).
    UnsupportedFormatError
        For a file name whose extension jointseg does not read (before any byte is stored).
    ConfigError
        For a request that is not multipart, lacks the file, or has an unknown field or a bad
        file name.
    """
    content_type, params = parse_options_header(request.headers.get("content-type", ""))
    if content_type != b"multipart/form-data" or b"boundary" not in params:
        raise UnsupportedFormatError(
            "expected a multipart/form-data request with the scan in form field 'file'"
        )
    length = request.headers.get("content-length")
    if length is not None and length.isdigit() and int(length) > max_bytes + MAX_CONFIG_BYTES:
        raise UploadTooLarge(f"upload is larger than the limit of {max_bytes:,} bytes")
    receiver = _Receiver(storage, max_bytes)
    try:
        return await _parse(request, receiver, params[b"boundary"])
    except BaseException:
        if receiver.file is not None:
            receiver.file.close()
        if receiver.upload is not None:
            receiver.upload.path.unlink(missing_ok=True)
        raise


async def _parse(request: Request, receiver: _Receiver, boundary: bytes) -> ReceivedUpload:
    callbacks = {
        name: getattr(receiver, name)
        for name in (
            "on_part_begin",
            "on_part_data",
            "on_part_end",
            "on_header_field",
            "on_header_value",
            "on_header_end",
            "on_headers_finished",
        )
    }
    parser = MultipartParser(boundary, callbacks)  # type: ignore[arg-type]
    batch = 0
    try:
        async for chunk in request.stream():
            parser.write(chunk)
            batch += len(chunk)
            if receiver.file is not None and batch >= WRITE_BATCH:
                await anyio.to_thread.run_sync(receiver.file.write, receiver.take_pending())
                batch = 0
        parser.finalize()
    except FormParserError as exc:
        raise ConfigError(f"malformed multipart body: {exc}") from exc
    if receiver.upload is None or receiver.file is None:
        raise ConfigError(f"form field {FILE_FIELD!r} (the scan) is required")
    await anyio.to_thread.run_sync(receiver.file.write, receiver.take_pending())
    receiver.file.close()
    upload = receiver.upload
    upload.size = receiver.size
    if receiver.config is not None:
        upload.config = receiver.config.decode("utf-8", "replace")
    return upload
