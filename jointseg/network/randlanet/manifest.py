"""Which cached exports serve a weights file: the manifest the torch-free compiled network reads.

Written by the torch side (:class:`~jointseg.network.randlanet.engine.CompiledForward`) each time
it compiles a crop shape for a model still as read from its file, and read by
:mod:`jointseg.network.randlanet.compiled`. Keyed by the file's SHA-1, so a changed file is
compiled again; holds the model's card and configuration, and the export of each input shape.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path
from typing import Any

from jointseg.io.atomic import atomic_open
from jointseg.lru import LRUCache
from jointseg.network.randlanet.config import RandLANetConfig
from jointseg.network.randlanet.ov_runtime import cache_dir

log = logging.getLogger(__name__)

#: Bumped when what a manifest means changes; older manifests are then ignored.
MANIFEST_VERSION = 1
#: Crop shapes a manifest remembers (as the torch side compiles at most a few per model).
MAX_MANIFEST_SHAPES = 8
#: The SHA-1 of recently read weights files, by identity (device, inode, size, mtime).
_DIGESTS: LRUCache[tuple[int, int, int, int], str] = LRUCache(16)


def weights_digest(path: Path) -> str:
    """SHA-1 of a weights file's bytes (about 10 ms for the bundled 9 MB), remembered while the
    file is unchanged."""
    st = path.stat()
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)

    def digest() -> str:
        h = hashlib.sha1()
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        return h.hexdigest()

    return _DIGESTS.get_or_load(key, digest)


def manifest_path(weights: Path, folder: Path | None = None) -> Path:
    """Where the manifest of the weights file ``weights`` lives in the cache folder."""
    return (folder or cache_dir()) / f"weights-{weights_digest(weights)[:20]}.json"


def shape_key(flat: list[Any]) -> str:
    """The inputs' shapes as the manifest keys them."""
    return json.dumps([list(a.shape) for a in flat])


def read_manifest(weights: Path, folder: Path | None = None) -> dict[str, Any] | None:
    """The manifest of ``weights``, or None when there is none (or an unreadable, foreign or
    older one: the torch path then compiles and writes it again)."""
    try:
        data = json.loads(manifest_path(weights, folder).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("version") != MANIFEST_VERSION:
        return None
    if not isinstance(data.get("shapes"), dict) or not isinstance(data.get("config"), dict):
        return None
    return data


def record_export(
    weights: Path,
    *,
    config: RandLANetConfig,
    card: dict[str, Any],
    shape: str,
    export: Path,
    folder: Path,
) -> None:
    """Add the export ``export`` of one input shape to the manifest of ``weights``. Written
    whole or not at all (other processes read the same cache); a failure only costs the next
    run its torch-free start, so it is logged, never raised."""
    try:
        data = read_manifest(weights, folder) or {
            "version": MANIFEST_VERSION,
            "weights": weights.name,
            "config": config.model_dump(mode="json"),
            "card": card,
            "shapes": {},
        }
        if data["shapes"].get(shape) == export.name or len(data["shapes"]) >= MAX_MANIFEST_SHAPES:
            return
        data["shapes"][shape] = export.name
        with atomic_open(manifest_path(weights, folder)) as fh:
            fh.write(json.dumps(data, default=str).encode())
    except (OSError, TypeError, ValueError) as exc:
        log.warning("could not record the compiled network for %s: %s", weights.name, exc)
