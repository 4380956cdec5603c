"""Published network weights by name, pulled into a local cache (`jointseg models pull NAME`).

Why a catalogue with pinned SHA-256 sums: weights are code-adjacent (a ``.t7`` or ``.pth`` file
is a pickle), so a file is used only once its bytes are the bytes that were published. A
download goes to ``NAME.part`` in the cache and is resumed from there with an HTTP range request
(within one command, and by running the command again); only a checked file is moved, in one
rename, to its final name, so the cache never holds a half-written or unchecked weights file.

Imports no torch: the Open3D-ML conversion is imported only when such a file arrives.
"""

from __future__ import annotations

import http.client
import json
import logging
import os
import urllib.error
import urllib.request
from pathlib import Path
from typing import Literal
from urllib.parse import urlsplit

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from jointseg import __version__
from jointseg.exceptions import ConfigError
from jointseg.network.digest import file_sha256
from jointseg.progress import ProgressFn, report

log = logging.getLogger(__name__)

STAGE = "download"
#: Folder of pulled weights; default ~/.cache/jointseg.
CACHE_ENV = "JOINTSEG_CACHE"
#: A JSON file of further entries (a list of objects with PublishedWeights' fields), e.g. an
#: organisation's own weights or a mirror of the public ones; its names win over built-in ones.
CATALOGUE_ENV = "JOINTSEG_MODELS_CATALOGUE"
CHUNK = 1 << 20

_DGCNN_SHA256 = {
    1: "16e562520eb07571ccefda0b3aff4ec2e8a1f959afce2770ab68ed4e814bcc17",
    2: "05d5914144449ffe56c5ce4426c10daf0310d13fb61f1ace897e0aaca0a728d2",
    3: "554f87d0302471d6636d358987b9b25b45807816960049290c995389afd056dd",
    4: "38d3f31f5a14afe5af3cae383256554fdc39cc9906fa993f4ddc835e638310e0",
    5: "ac72b13e1cdf0e73dac356aa77a429dcd08516fb81950356e2746a7d3e58fc6e",
    6: "c40c61c11b89e12daf17aab93528f8741210fbc9344d8883c25430ac8e36454d",
}
_DGCNN_URL = (
    "https://github.com/antao97/dgcnn.pytorch/raw/master/pretrained/semseg_s3dis/model_{}.t7"
)
_OPEN3D_ML_URL = (
    "https://storage.googleapis.com/open3d-releases/model-zoo/randlanet_s3dis_202201071330utc.pth"
)
#: The backends published weights can be for, and the suffix their cached files take (the one
#: that backend reads: a jointseg checkpoint, or dgcnn.pytorch's ``.t7``). Kept here, not read
#: from the registry, because the registry imports this module.
SUFFIXES: dict[str, str] = {"randlanet": ".pt", "dgcnn": ".t7"}
#: The DGCNN weights `--network dgcnn` uses when pulled and nothing else is given: model_5 leaves
#: S3DIS Area 5 out, the usual benchmark split.
DEFAULT_DGCNN = "dgcnn-s3dis-5"


class PublishedWeights(BaseModel):
    """One published weights file: where it lies, what its bytes hash to, what it is."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(pattern=r"^[a-z0-9][a-z0-9._-]{0,63}$")
    backend: Literal["randlanet", "dgcnn"]
    url: str
    sha256: str | None = Field(
        None,
        pattern=r"^[0-9a-f]{64}$",
        description="SHA-256 of the published file; None where its publisher gives none "
        "(pulling it then needs --unverified).",
    )
    convert: Literal["open3d-ml"] | None = Field(
        None, description="Converted into a jointseg checkpoint on arrival."
    )
    description: str = ""
    licence: str = ""

    @field_validator("url")
    @classmethod
    def _http(cls, url: str) -> str:
        if urlsplit(url).scheme not in ("http", "https") or not urlsplit(url).netloc:
            raise ValueError(f"not an http(s) address: {url!r}")
        return url

    @property
    def filename(self) -> str:
        """The file's name in the cache: the name and the suffix its backend reads."""
        return self.name + SUFFIXES[self.backend]


BUILT_IN: tuple[PublishedWeights, ...] = (
    *(
        PublishedWeights(
            name=f"dgcnn-s3dis-{i}",
            backend="dgcnn",
            url=_DGCNN_URL.format(i),
            sha256=sha,
            description=f"S3DIS, Area {i} left out (antao97/dgcnn.pytorch)",
            licence="MIT (weights); trained on S3DIS, research use",
        )
        for i, sha in _DGCNN_SHA256.items()
    ),
    PublishedWeights(
        name="randlanet-s3dis-open3d-ml",
        backend="randlanet",
        url=_OPEN3D_ML_URL,
        sha256=None,
        convert="open3d-ml",
        description="S3DIS, Open3D-ML model zoo (converted on arrival)",
        licence="MIT (Open3D-ML); trained on S3DIS, research use",
    ),
)


def cache_dir() -> Path:
    """Where pulled weights live: $JOINTSEG_CACHE/weights, default ~/.cache/jointseg/weights."""
    root = os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "jointseg"
    return Path(root) / "weights"


def catalogue() -> dict[str, PublishedWeights]:
    """Every known name: the built-in entries and those of $JOINTSEG_MODELS_CATALOGUE.

    Raises
    ------
    ConfigError
        When the catalogue file is unreadable, not JSON, or an entry is invalid (naming the file,
        the entry and the field).
    """
    known = {entry.name: entry for entry in BUILT_IN}
    path = os.environ.get(CATALOGUE_ENV)
    if not path:
        return known
    try:
        raw = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"{CATALOGUE_ENV}={path}: cannot read it ({exc.strerror})") from exc
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: not JSON (line {exc.lineno}: {exc.msg})") from exc
    if not isinstance(raw, list):
        raise ConfigError(f"{path}: expected a JSON list of weights entries")
    for i, item in enumerate(raw):
        try:
            entry = PublishedWeights.model_validate(item)
        except ValidationError as exc:
            err = exc.errors()[0]
            where = ".".join(str(p) for p in err["loc"]) or "entry"
            raise ConfigError(f"{path}: entry {i}: {where}: {err['msg']}") from exc
        known[entry.name] = entry
    return known


def lookup(name: str) -> PublishedWeights:
    """The entry called ``name``; a ConfigError listing the known names otherwise."""
    known = catalogue()
    if name not in known:
        raise ConfigError(f"unknown weights {name!r}; known: {', '.join(sorted(known))}")
    return known[name]


def pulled_path(name: str) -> Path | None:
    """The cached file of ``name`` when it has been pulled, else None."""
    entry = catalogue().get(name)
    if entry is None:
        return None
    path = cache_dir() / entry.filename
    return path if path.is_file() else None


def pull(
    name: str,
    *,
    progress: ProgressFn | None = None,
    retries: int = 3,
    unverified: bool = False,
    force: bool = False,
    timeout: float = 30.0,
) -> Path:
    """Download ``name`` into the cache (resuming a broken download), check it, return its path.

    Parameters
    ----------
    retries : int
        Further attempts, each resuming where the last stopped, after a connection breaks.
    unverified : bool
        Accept an entry without a published SHA-256 (its hash is logged and, for a converted
        file, kept in the checkpoint's card).
    force : bool
        Download again even when the file is already in the cache.

    Raises
    ------
    ConfigError
        One line each: unknown name, no published checksum without ``unverified``, HTTP error
        (e.g. 404), host unreachable, a download still broken after ``retries`` (the partial file
        stays for the next run to resume), checksum mismatch (the download is deleted).
    """
    entry = lookup(name)
    folder = cache_dir()
    final = folder / entry.filename
    if final.is_file() and not force:
        report(progress, STAGE, 1.0)
        return final
    if entry.sha256 is None and not unverified:
        raise ConfigError(
            f"{name}: its publisher gives no SHA-256, so the file cannot be checked; pass "
            "--unverified to accept it as downloaded"
        )
    folder.mkdir(parents=True, exist_ok=True)
    part = folder / (entry.filename + ".part")
    _download(entry, part, progress=progress, retries=retries, timeout=timeout)
    digest = file_sha256(part)
    if entry.sha256 is not None and digest != entry.sha256:
        part.unlink()
        raise ConfigError(
            f"{name}: checksum mismatch (expected SHA-256 {entry.sha256}, got {digest}); "
            "the download was deleted"
        )
    if entry.sha256 is None:
        log.warning("%s: accepted without a published checksum; SHA-256 %s", name, digest)
    if entry.convert == "open3d-ml":
        from jointseg.network.convert import import_open3d_ml

        # under its published name, so the converter's card names the source file
        raw = folder / ".converting" / Path(urlsplit(entry.url).path).name
        tmp = folder / ".converting" / entry.filename
        raw.parent.mkdir(exist_ok=True)
        part.replace(raw)
        try:
            import_open3d_ml(raw, tmp)
            tmp.replace(final)
        finally:
            for leftover in (tmp, raw):
                leftover.unlink(missing_ok=True)
            raw.parent.rmdir()
    else:
        part.replace(final)
    report(progress, STAGE, 1.0)
    log.info("pulled %s -> %s", name, final)
    return final


def _download(
    entry: PublishedWeights,
    part: Path,
    *,
    progress: ProgressFn | None,
    retries: int,
    timeout: float,
) -> None:
    """Fill ``part`` with the whole file at ``entry.url``, resuming what is already there."""
    host = urlsplit(entry.url).netloc
    for attempt in range(retries + 1):
        have = part.stat().st_size if part.is_file() else 0
        headers = {"User-Agent": f"jointseg/{__version__}"}
        if have:
            headers["Range"] = f"bytes={have}-"
        request = urllib.request.Request(entry.url, headers=headers)
        try:
            with urllib.request.urlopen(request, timeout=timeout) as response:
                if have and response.status != 206:  # the server ignored the range: start over
                    have = 0
                length = response.headers.get("Content-Length")
                total = have + int(length) if length is not None else None
                with part.open("ab" if have else "wb") as out:
                    while chunk := response.read(CHUNK):
                        out.write(chunk)
                        have += len(chunk)
                        if total:
                            report(progress, STAGE, 0.99 * have / total)
            if total is not None and have < total:
                raise http.client.IncompleteRead(b"", total - have)
            return
        except urllib.error.HTTPError as exc:
            if exc.code == 416 and have:  # nothing left to fetch: the part is whole
                return
            raise ConfigError(
                f"{entry.name}: {entry.url} answered HTTP {exc.code} {exc.reason}"
            ) from exc
        except (TimeoutError, urllib.error.URLError, http.client.HTTPException, OSError) as exc:
            reason = getattr(exc, "reason", None) or exc.__class__.__name__
            have = part.stat().st_size if part.is_file() else 0
            if attempt < retries:
                log.warning("%s: broke at %d bytes (%s); resuming", entry.name, have, reason)
                continue
            if have == 0:
                part.unlink(missing_ok=True)
                raise ConfigError(
                    f"{entry.name}: cannot reach {host} ({reason}); check the connection or "
                    f"download {entry.url} by hand and pass it with --weights"
                ) from exc
            raise ConfigError(
                f"{entry.name}: download broke after {have:,} bytes ({reason}); run `jointseg "
                f"models pull {entry.name}` again to resume"
            ) from exc
