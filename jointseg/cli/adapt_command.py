"""`jointseg adapt`: a model that has learnt from corrected results (issue 66), for
``jointseg segment --weights MODEL`` on the next scans of the same site and sensor."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from jointseg.exceptions import ConfigError

RESULTS_HELP = (
    "Results of `jointseg segment` with users' corrections (the user_label field that "
    "`jointseg relabel`, the viewer and the service's labels versions write)."
)


def _to_work(path: Path) -> np.ndarray:
    """The transform to the run's work frame from its report (``frame.to_work``)."""
    from jointseg.cli.relabel_command import read_json

    body = read_json(path, "--report")
    matrix = ((body or {}).get("frame") or {}).get("to_work") if isinstance(body, dict) else None
    try:
        out = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        out = np.zeros(0)
    if out.shape != (4, 4) or not np.isfinite(out).all():
        raise ConfigError(f"--report {path}: no frame.to_work matrix; is it a run's report?")
    return out


def adapt_command(
    results: list[Path] = typer.Argument(..., help=RESULTS_HELP),
    out: Path = typer.Option(..., "-o", "--out", help="The adapted model to write (.pt)."),
    report: list[Path] = typer.Option(
        [],
        "--report",
        help="Each result's report.json, in the results' order (their frames place the points "
        "as the runs did; default: the frame is decided again, as the pipeline decides it).",
    ),
    weights: Path | None = typer.Option(
        None, "--weights", help="The model to adapt (default: the bundled network)."
    ),
    steps: int | None = typer.Option(None, min=1, help="Steps of the head's fit (default 300)."),
    replay_rooms: int | None = typer.Option(
        None,
        min=0,
        max=20,
        help="Generated rooms whose points hold the head to the base network, so classes "
        "nobody corrected keep their labels (default 4; 0 learns from your scans alone).",
    ),
    keep_base_above: float | None = typer.Option(
        None,
        min=0.01,
        max=1.0,
        help="Keep the bundled network's answer where its top probability reaches this (the "
        "adapted head elsewhere): other buildings keep their labels, re-scans gain less "
        "(docs/benchmarks/corrections.md; default: the adapted head everywhere).",
    ),
    min_base_probability: float | None = typer.Option(
        None,
        min=0.0,
        max=0.999,
        help="Leave out corrected points whose class the bundled network gives less than "
        "this where they are a minority of their corrected segment (the points of another "
        "object a segment corrected whole held; default 0.01; 0 learns from every corrected "
        "point).",
    ),
) -> None:
    """Learn from corrected results: the network's head refitted to the users' classes."""
    from jointseg.adapt.head import AdaptParams
    from jointseg.adapt.learn import Corrected, adapt
    from jointseg.cli.progress_bar import progress_bar
    from jointseg.pipeline import load_predictor
    from jointseg.pipeline.config import PipelineConfig

    if out.suffix.lower() != ".pt":
        raise ConfigError(f"--out {out}: an adapted model is a .pt file")
    if report and len(report) != len(results):
        raise ConfigError(f"--report given {len(report)} times for {len(results)} results")
    for path in results:
        if not path.is_file():
            raise ConfigError(f"{path}: no such file")
    to_work: list[np.ndarray | None] = [_to_work(p) for p in report] or [None] * len(results)
    cfg = PipelineConfig().with_network(weights=weights)
    given = {
        "steps": steps,
        "replay_rooms": replay_rooms,
        "keep_base_above": keep_base_above,
        "min_base_probability": min_base_probability,
    }
    params = AdaptParams(**{k: v for k, v in given.items() if v is not None})
    predictor = load_predictor(cfg.network)
    items = [Corrected(p, p.name, None, m) for p, m in zip(results, to_work, strict=True)]
    with progress_bar() as progress:
        done = adapt(items, out, predictor=predictor, choice=cfg.network.choice(), params=params,
                     progress=progress)  # fmt: skip
    info = done.card["adapted"]
    typer.echo(
        f"learnt from {info['corrected_points']:,} corrected points of {len(results)} results "
        f"in {info['seconds']:.0f} s -> {out} (use: jointseg segment --weights {out})",
        err=True,
    )


def register(app: typer.Typer) -> None:
    """Add this module's commands to ``app``."""
    app.command("adapt")(adapt_command)
