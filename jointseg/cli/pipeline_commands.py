"""`jointseg segment` (the whole method on one scan) and `jointseg eval` (the paper's tables).

Everything that can be checked before the work starts is checked first (configuration, network
weights, output paths, ground truth for eval), so a mistake costs no computing time and leaves
no output behind; outputs are written atomically at the end.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from jointseg.cli.progress_bar import progress_bar
from jointseg.config_file import load_params_file
from jointseg.exceptions import ConfigError, ScanFormatError
from jointseg.io import DEFAULT_MAX_POINTS, READ_EXTENSIONS, probe_scan, read_scan
from jointseg.io.atomic import atomic_open
from jointseg.network.registry import BACKENDS

if TYPE_CHECKING:  # the pipeline (torch, open3d) is imported by the commands that run it
    from jointseg.network.backends import Predictor
    from jointseg.network.pending import PendingPredictor
    from jointseg.pipeline.config import PipelineConfig
    from jointseg.pipeline.segment import SegmentedFile

log = logging.getLogger(__name__)

#: Output formats that keep per-point fields (text formats would drop them).
FIELD_EXTENSIONS = (".ply", ".las", ".laz", ".pcd", ".npz")

SCAN_HELP = (
    f"Input scan ({', '.join(READ_EXTENSIONS)}; meshes are sampled to points) or S3DIS room folder."
)
CONFIG_HELP = "PipelineConfig as JSON: network, geometry, fusion, seed (unknown keys rejected)."
NETWORK_HELP = f"Network backend: {', '.join(BACKENDS)} (overrides the config file)."
WEIGHTS_HELP = (
    "Network weights: a file or pulled published weights by name (overrides the config file; "
    "default: the backend's environment variable, else its bundled or pulled weights; "
    "`jointseg models list` shows them)."
)
DEVICE_HELP = (
    "Where the network runs: cpu, cuda or cuda:N (overrides the config's network.device; "
    "default: cuda when present)."
)


def _config(
    config: Path | None,
    network: str | None,
    weights: Path | None,
    device: str | None,
    quality: str | None = None,
) -> PipelineConfig:
    """The run's config: the file's, with the command line's overrides, and its device checked
    now (CUDA asked for on a machine without it fails before any reading or output)."""
    from jointseg.pipeline.config import PipelineConfig

    extra: dict[str, object] | None = None if quality is None else {"quality": quality}
    cfg = load_params_file(config, PipelineConfig, extra).with_network(
        name=network, weights=weights, device=device
    )
    if cfg.network.device not in (None, "", "cpu"):  # only a named device needs torch to check
        from jointseg.network.base import pick_device

        pick_device(cfg.network.device)
    return cfg


def with_frame(
    cfg: PipelineConfig, up: str | None, units: str | None, colour_free: str | None
) -> PipelineConfig:
    """The config with the command line's frame and colour-free overrides, validated like a
    config file's (a bad value is refused before any work)."""
    from pydantic import ValidationError

    from jointseg.pipeline.config import PipelineConfig

    body = cfg.model_dump(mode="json")
    if up is not None:
        body["frame"]["up"] = up
    if units is not None:
        body["frame"]["units"] = units
    if colour_free is not None:
        body["network"]["colour_free"] = colour_free
    try:
        return PipelineConfig.model_validate(body)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise ConfigError(f"{where}: {first['msg']}") from None


def _check_writable(path: Path | None, what: str) -> None:
    if path is None:
        return
    if not path.parent.is_dir():
        raise ConfigError(f"{what} {path}: folder {path.parent} does not exist")
    if path.is_dir():
        raise ConfigError(f"{what} {path}: is a directory; give a file name")


def _check_outputs(
    output: Path, report: Path | None, objects_out: Path | None, ifc: Path | None
) -> None:
    """Refuse, before any work, an output that cannot hold the fields or any file that
    cannot be written."""
    if output.suffix.lower() not in FIELD_EXTENSIONS:
        raise ConfigError(
            f"{output}: cannot store the output fields in {output.suffix or 'no extension'!r}; "
            f"use one of {', '.join(FIELD_EXTENSIONS)}"
        )
    _check_writable(output, "output")
    for path, what in ((report, "report"), (objects_out, "objects"), (ifc, "IFC model")):
        _check_writable(path, what)


def _write_text(path: Path, text: str) -> None:
    with atomic_open(path) as fh:
        fh.write(text.encode())


def _import_pipeline(network: str | None) -> None:
    """Import the code a run needs (seconds): open3d without its viewer
    (:func:`~jointseg.lazy.import_open3d`), the pipeline, and the network's backend (torch)
    unless ``network`` is None (it loads in a thread: :func:`_load_beside`), so
    ``load_network`` in the report times the network's loading, not imports."""
    from jointseg.lazy import import_open3d
    from jointseg.network.registry import import_backend

    started = time.perf_counter()
    import_open3d()  # first: the pipeline imports open3d
    import jointseg.pipeline.segment  # noqa: F401 - imported here to be timed

    if network is not None:
        import_backend(network)
    log.info("imports: %.2f s", time.perf_counter() - started)


def _load_beside(cfg: PipelineConfig) -> PendingPredictor:
    """The network loading in a thread (torch's import, then the weights: seconds) while this
    one imports the pipeline and the run reads the scan, decides its frame and segments its
    geometry (:mod:`jointseg.network.pending`). Missing weights are refused here, before
    anything else runs; an unreadable file fails the run when the network is first needed."""
    from jointseg.network.pending import PendingPredictor
    from jointseg.network.registry import import_backend, load_fast, locate

    net = cfg.network
    compiled: list[Predictor] = []

    def prepare() -> None:
        """The torch-free compiled network when its cache serves these weights (nothing to
        import then); else the backend's imports (torch)."""
        fast = load_fast(net.name, net.weights, device=net.device, batch_size=net.batch_size,
                         params=net.options())  # fmt: skip
        if fast is None:
            import_backend(net.name)
        else:
            compiled.append(fast)

    def load() -> Predictor:
        from jointseg.pipeline.stages import load_predictor

        if compiled:
            warm = getattr(compiled[0], "prepare", None)
            if warm is not None:  # the forward pass compiled here, beside the scan's reading
                warm()
            return compiled[0]
        return load_predictor(net)

    locate(net.name, net.weights)
    pending = PendingPredictor(prepare, load)
    _import_pipeline(None)
    return pending


def segment_scan(
    source: Path = typer.Argument(..., help=SCAN_HELP),
    output: Path = typer.Option(
        ..., "-o", "--output", help="Output scan (.ply, .las or .laz) with the pipeline's fields."
    ),
    report: Path | None = typer.Option(None, "--report", help="Write a JSON report here."),
    objects_out: Path | None = typer.Option(
        None, "--objects", help="Write objects.json (objects, rooms, walls) here."
    ),
    ifc: Path | None = typer.Option(None, "--ifc", help="Write an IFC4 model of it here."),
    network: str | None = typer.Option(None, "--network", help=NETWORK_HELP),
    weights: Path | None = typer.Option(None, "--weights", help=WEIGHTS_HELP),
    config: Path | None = typer.Option(None, "--config", help=CONFIG_HELP),
    device: str | None = typer.Option(None, "--device", help=DEVICE_HELP),
    max_points: int = typer.Option(DEFAULT_MAX_POINTS, help="Refuse larger scans."),
    tile_points: int | None = typer.Option(
        None,
        "--tile-points",
        min=1000,
        help="Cut scans with more points into tiles of about this many (bounded memory; "
        "default: the config's tiles.max_points, 4 000 000).",
    ),
    work_dir: Path | None = typer.Option(
        None,
        "--work-dir",
        help="Folder for a tiled run's spilled scan and tile results (about 60 bytes a point; "
        "default: a temporary folder beside the output, removed at the end).",
    ),
    up: str | None = typer.Option(
        None, "--up", help="auto, +z, -z, +y, -y, +x or -x: the file axis that points up."
    ),
    units: str | None = typer.Option(
        None, "--units", help="auto, m, cm, mm, ft, us-ft or in: the coordinates' unit."
    ),
    colour_free: str | None = typer.Option(
        None,
        "--colour-free",
        help="auto, on or off: the colour-free network (auto: for scans without colour).",
    ),
    quality: str | None = typer.Option(
        None,
        "--quality",
        help="fast (previews, big floors), standard (default) or best (views of every crop, "
        "every installed network averaged); settings in --config still win.",
    ),
) -> None:
    """Segment a scan semantically: network labels refined by geometric segments (the paper).

    A scan with more points than the tile size is processed tile by tile in bounded memory,
    with the same labels as a run on the whole scan on all but a few border points.
    """
    cfg = with_frame(_config(config, network, weights, device, quality), up, units, colour_free)
    if tile_points is not None:
        cfg = cfg.model_copy(
            update={"tiles": cfg.tiles.model_copy(update={"max_points": tile_points})}
        )
    _check_outputs(output, report, objects_out, ifc)
    info = probe_scan(source, max_points=max_points)
    if work_dir is not None and not work_dir.is_dir():
        raise ConfigError(f"--work-dir {work_dir}: not a folder")
    predictor = _load_beside(cfg)  # torch and the weights, while the scan is read
    from jointseg.pipeline import segment_file

    with progress_bar() as progress:
        done = segment_file(
            source,
            output,
            cfg,
            predictor=predictor,
            max_points=max_points,
            points=info.n_points,
            progress=progress,
            workdir=work_dir,
        )
    _finish(done, report, output)
    _write_objects(done, objects_out, ifc, source.stem)


def _write_objects(
    done: SegmentedFile, objects_out: Path | None, ifc: Path | None, name: str
) -> None:
    """``--objects`` and ``--ifc``: the run's layout as objects.json and an IFC model."""
    if objects_out is None and ifc is None:
        return
    from jointseg.cli.objects_command import layout_from_report, write_layout
    from jointseg.memory import release_memory

    release_memory()  # the run's freed arrays go back first: the IFC model does not add on top
    typer.echo(write_layout(layout_from_report(done.report), objects_out, ifc, name), err=True)


def _finish(done: SegmentedFile, report: Path | None, output: Path) -> None:
    """Write the report (when asked for) and print the one-line summary of a run."""
    from jointseg.pipeline.tables import format_score

    body = done.report
    if report is not None:
        _write_text(report, json.dumps(body, indent=2))
    frame = body.get("frame")
    if frame is not None:
        from jointseg.frame.decide import summary_line

        typer.echo(summary_line(frame), err=True)
        for warning in frame["warnings"]:
            typer.echo(f"warning: {warning}", err=True)
    where = "" if done.tiles is None else f" in {done.tiles} tiles"
    line = (
        f"{body['points']:,} points{where} -> {body['segments']:,} segments, "
        f"{body['labels_changed']:,} labels changed by fusion, "
        f"{body['timings_s']['total']:.1f} s -> {output}"
    )
    if done.metrics is not None:
        network, fused, oracle = (
            format_score(done.metrics[k].miou) for k in ("network", "fused", "oracle")
        )
        line += f"\nmIoU network {network} -> fused {fused} (oracle {oracle})"
    typer.echo(line, err=True)


def _scan_paths(paths: list[Path]) -> list[Path]:
    """Files (and S3DIS room folders) named, or found directly inside named folders."""
    found: list[Path] = []
    for path in paths:
        if not path.exists():
            raise ScanFormatError(f"{path}: file not found")
        if path.is_dir() and not (path / "Annotations").is_dir():
            inside = sorted(
                p for p in path.iterdir() if p.is_file() and p.suffix.lower() in READ_EXTENSIONS
            )
            inside += sorted(p for p in path.iterdir() if (p / "Annotations").is_dir())
            if not inside:
                raise ScanFormatError(f"{path}: no scan files ({', '.join(READ_EXTENSIONS)})")
            found.extend(inside)
        else:
            found.append(path)
    return found


def evaluate_scans(
    paths: list[Path] = typer.Argument(..., help="Labelled scans, or folders of them."),
    network: str | None = typer.Option(None, "--network", help=NETWORK_HELP),
    weights: Path | None = typer.Option(None, "--weights", help=WEIGHTS_HELP),
    config: Path | None = typer.Option(None, "--config", help=CONFIG_HELP),
    device: str | None = typer.Option(None, "--device", help=DEVICE_HELP),
    out: Path | None = typer.Option(
        None, "--out", help="Folder for table1.csv, table2.csv and eval.json (created)."
    ),
    max_points: int = typer.Option(DEFAULT_MAX_POINTS, help="Refuse larger scans."),
) -> None:
    """Run the pipeline on labelled scans and print the paper's Table 1 and Table 2."""
    cfg = _config(config, network, weights, device)
    scans = _scan_paths(paths)
    for path in scans:  # refuse unlabelled input before any work
        if not probe_scan(path, max_points=max_points).has_labels:
            raise ConfigError(f"{path}: has no ground-truth labels; eval needs labelled scans")
    if out is not None and out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: exists and is not a folder")
    _import_pipeline(cfg.network.name)
    from jointseg.pipeline import load_predictor, report_body, run
    from jointseg.pipeline.tables import RoomScores, format_table, table1, table2, to_csv

    predictor = load_predictor(cfg.network)
    rooms: list[RoomScores] = []
    details: list[dict[str, Any]] = []
    with progress_bar() as progress:
        for i, path in enumerate(scans):
            prefix = f"{i + 1}/{len(scans)} "

            def room_progress(stage: str, fraction: float, prefix: str = prefix) -> None:
                progress(prefix + stage, fraction)

            scan = read_scan(path, max_points=max_points, progress=room_progress)
            result = run(scan, cfg, room_progress, predictor=predictor)
            if result.metrics is None:  # labels present in the header but all -1
                raise ConfigError(f"{path}: has no ground-truth labels; eval needs labelled scans")
            name = path.stem if path.is_file() else path.name
            rooms.append(RoomScores(name, result.metrics))
            details.append({"name": name, "path": str(path), **report_body(scan, result)})
    t1, t2 = table1(rooms), table2(rooms)
    typer.echo("Table 1. IoU per class (network and fused labels)\n")
    typer.echo(format_table(*t1))
    typer.echo("\nTable 2. mIoU and mAcc\n")
    typer.echo(format_table(*t2))
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        _write_text(out / "table1.csv", to_csv(*t1))
        _write_text(out / "table2.csv", to_csv(*t2))
        body = {
            "table1": {"header": t1[0], "rows": t1[1]},
            "table2": {"header": t2[0], "rows": t2[1]},
            "rooms": details,
        }
        _write_text(out / "eval.json", json.dumps(body, indent=2))
        typer.echo(f"\nwrote {out / 'table1.csv'}, {out / 'table2.csv'}, {out / 'eval.json'}")


def register(app: typer.Typer) -> None:
    """Add this module's commands to ``app``."""
    app.command("segment")(segment_scan)
    app.command("eval")(evaluate_scans)
