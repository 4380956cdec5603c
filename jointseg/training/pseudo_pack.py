"""The prepared run's self-training source: unlabelled real scans labelled by the pipeline
(:mod:`jointseg.training.pseudo`) as a ``pseudo/`` folder of pack arrays beside
``s3dis_area6/``, ``scannet/`` and ``synth/``, and its entry in the pack's manifest.

By default the unlabelled scans of ``../shared/data``: the other sensors' captures and the
RGB-D fragment. Scans whose truth the pack already carries (the tuning ScanNet scans, camera
views of the training rooms) are not pseudo-labelled: their own labels teach more than the
pipeline's guesses, so they serve only to choose the rule (``bench/pseudo_labels.py``). The
judging and validation scans are refused outright.

    python -m jointseg.training.pseudo_pack --shared ../shared/data --out .gpu/data
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from jointseg.exceptions import ConfigError
from jointseg.scan import Scan
from jointseg.training.prepared import JUDGING, VALIDATION, write_arrays
from jointseg.training.pseudo import (
    PSEUDO_VERSION,
    PseudoRule,
    pseudo_label,
    read_unlabelled,
)
from jointseg.training.sources import PSEUDO_TERMS, matches

if TYPE_CHECKING:
    from jointseg.network.backends import Predictor

log = logging.getLogger(__name__)

#: The source folder (and its name in SHARES, the manifest and the model card).
PSEUDO = "pseudo"
#: Scans whose ``rgb`` is no colour (../shared/data/README.md: PCL's region-growing tutorial
#: holds segment colours there): labelled and stored without it, so the colour network is
#: neither misled by it now nor taught on it later.
FALSE_COLOUR = ("pcldata_region_growing_tutorial",)


def default_inputs(shared: Path) -> list[Path]:
    """The unlabelled real scans of ``../shared/data``."""
    files = sorted((shared / "other_sensors").glob("*.pcd"))
    lone = shared / "real_indoor_unlabelled.pcd"
    files += [lone] if lone.is_file() else []
    if not files:
        raise ConfigError(f"{shared}: no other_sensors/*.pcd and no real_indoor_unlabelled.pcd")
    return files


def refuse_held_out(paths: list[Path]) -> None:
    """A judging or validation scan must never become training data, not even unlabelled."""
    held = [p.name for p in paths if matches(p.stem, [f"{j}*" for j in JUDGING] + [*VALIDATION])]
    if held:
        raise ConfigError(f"judging or validation scans cannot be pseudo-labelled: {held}")
    stems = [p.stem for p in paths]
    if len(set(stems)) != len(stems):
        raise ConfigError(f"scans with the same name would overwrite each other: {stems}")


def write_pseudo(
    out: Path, inputs: list[Path], rule: PseudoRule, predictor: Predictor | None = None
) -> dict[str, Any]:
    """Pseudo-label ``inputs`` into ``out/pseudo/`` and name them in ``out/manifest.json``;
    returns the manifest's ``pseudo`` section.

    Every input is read before anything is written, and the folder is built aside and moved
    into place at the end: a bad input or a failed run leaves the previous folder as it was.
    """
    refuse_held_out(inputs)
    scans = [(p, read_unlabelled(p)) for p in inputs]
    if predictor is None:
        from jointseg.pipeline import PipelineConfig, load_predictor

        predictor = load_predictor(PipelineConfig().network)
    out.mkdir(parents=True, exist_ok=True)
    aside = out / f".{PSEUDO}.partial"
    shutil.rmtree(aside, ignore_errors=True)
    entries: dict[str, Any] = {}
    try:
        for path, scan in scans:
            if path.stem in FALSE_COLOUR:
                scan = Scan(scan.xyz, None, None, source_format=scan.source_format)
            entries[path.stem] = _label_one(path, scan, rule, predictor, aside)
    except BaseException:
        shutil.rmtree(aside, ignore_errors=True)
        raise
    shutil.rmtree(out / PSEUDO, ignore_errors=True)
    aside.mkdir(exist_ok=True)  # every scan may have been skipped
    aside.rename(out / PSEUDO)
    section = _section(rule, entries)
    _update_manifest(out, section)
    return section


def _label_one(
    path: Path, scan: Scan, rule: PseudoRule, predictor: Predictor, folder: Path
) -> dict[str, Any]:
    """One scan labelled and written (unless nothing was sure); its manifest entry."""
    labelled, result = pseudo_label(scan, rule, predictor)
    counts = labelled.counts()
    kept = len(labelled.labels) - counts["unlabelled"]
    entry: dict[str, Any] = {
        "source": str(path),
        "points": len(labelled.labels),
        "kept": kept,
        "per_class": counts,
        "up": labelled.up,
        "floor_read": labelled.evidence.floor,
        "by_structure": int(((labelled.evidence.structure >= 0) & (labelled.labels >= 0)).sum()),
        "colour": labelled.rgb is not None,
        "network": Path(str(result.params["network"]["weights"])).name,
    }
    if kept == 0:  # a scan without a label would stop the trainer
        log.warning("%s: no label sure enough, left out", path)
        entry["skipped"] = "no label sure enough"
        return entry
    write_arrays(labelled.xyz, labelled.rgb, labelled.labels, folder / f"{path.stem}.npz")
    log.info("%s: %d of %d points kept %s", path.name, kept, len(labelled.labels), counts)
    return entry


def _section(rule: PseudoRule, entries: dict[str, Any]) -> dict[str, Any]:
    from jointseg import __version__

    totals: dict[str, int] = {}
    for e in entries.values():
        for name, n in e["per_class"].items():
            totals[name] = totals.get(name, 0) + n
    return {
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "pipeline": f"jointseg {__version__}, default configuration, pseudo-labels v"
        f"{PSEUDO_VERSION}",
        "rule": rule.model_dump(),
        "rule_text": rule.describe(),
        "terms": PSEUDO_TERMS,
        "totals": totals,
        "scans": entries,
    }


def _update_manifest(out: Path, section: dict[str, Any]) -> None:
    path = out / "manifest.json"
    manifest = json.loads(path.read_text()) if path.is_file() else {"scans": {}}
    written = [name for name, e in section["scans"].items() if "skipped" not in e]
    manifest.setdefault("scans", {})[PSEUDO] = written
    manifest.setdefault("terms", {})[PSEUDO] = PSEUDO_TERMS
    manifest[PSEUDO] = section
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(manifest, indent=1) + "\n")
    tmp.replace(path)


def main(argv: list[str] | None = None) -> int:
    """``--shared`` (or ``--scan``s) into ``--out``; the exit status."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--shared", type=Path, default=None, help="../shared/data")
    ap.add_argument("--scan", type=Path, action="append", default=[], help="a scan (repeatable)")
    ap.add_argument("--out", type=Path, required=True, help="the pack's folder (.gpu/data)")
    default = PseudoRule()
    for name in ("structure", "share", "prob"):
        ap.add_argument(f"--{name}", type=float, default=getattr(default, name))
    ap.add_argument("--vote-without-floor", action="store_true", help="the vote's labels on "
                    "scans without a floor too")  # fmt: skip
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    try:
        rule = PseudoRule(structure=args.structure, share=args.share, prob=args.prob,
                          vote_needs_floor=not args.vote_without_floor)  # fmt: skip
        inputs = list(args.scan) + (default_inputs(args.shared) if args.shared else [])
        if not inputs:
            raise ConfigError("nothing to label: give --shared or --scan")
        section = write_pseudo(args.out, inputs, rule)
    except (ConfigError, ValueError) as err:
        log.error("%s", err)
        return 2
    log.info("pseudo-labelled %d scans: %s", len(section["scans"]), section["totals"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
