"""`jointseg fit vote` and `jointseg fit up-axis`: the models the library ships, fitted from
named tuning scans, each written with its provenance beside it.

Why commands of the package: a shipped model is reproduced by running the command its
provenance names on the same scans, which gives the same file (``bench/`` only measures).
"""

from __future__ import annotations

import shlex
from pathlib import Path

import typer

fit_app = typer.Typer(
    help="Fit the models the library ships from named tuning scans (the vote needs the 'fit' "
    "extra: pip install 'jointseg\\[fit]').",
    no_args_is_help=True,
)

PLAN_HELP = "The fit plan (JSON): the tuning scans, who labels them, the settings."
OUT_HELP = "Where the model goes; its provenance is written beside it (<name>.provenance.json)."
CACHE_HELP = "Keep the networks' and the geometry's outputs here, for the next fit."


def _command(name: str, plan: Path, out: Path, cache: Path | None, **options: object) -> str:
    """The command line that reproduces this fit, from the options as parsed (whatever the
    command was started from)."""
    parts = ["jointseg", "fit", name, "--plan", str(plan), "--out", str(out)]
    if cache is not None:
        parts += ["--cache", str(cache)]
    for key, value in options.items():
        flag = "--" + key.replace("_", "-")
        if isinstance(value, bool):
            parts.append(flag if value else f"--no-{key.replace('_', '-')}")
        elif value is not None:
            parts += [flag, str(value)]
    return shlex.join(parts)


@fit_app.command("vote")
def vote(
    plan: Path = typer.Option(..., "--plan", help=PLAN_HELP),
    out: Path = typer.Option(..., "--out", "-o", help=OUT_HELP),
    cache: Path | None = typer.Option(None, "--cache", help=CACHE_HELP),
    trees: int | None = typer.Option(None, min=1, help="Trees (default: the plan's)."),
    depth: int | None = typer.Option(None, min=1, help="Depth of each tree."),
    min_leaf: int | None = typer.Option(None, min=1, help="Least samples per leaf."),
    l2: float | None = typer.Option(None, min=0, help="L2 regularisation of the leaves."),
    learning_rate: float | None = typer.Option(None, help="Learning rate of the boosting."),
    monotonic: bool | None = typer.Option(
        None, help="Monotone in the support of the offer and of the point's own label."
    ),
    structure: bool | None = typer.Option(None, help="Offer the geometry's structure reading."),
) -> None:
    """Fit the learned vote (jointseg/fusion/vote_model.json) on the plan's labelled scans."""
    from jointseg.fitting.vote import read_plan
    from jointseg.fitting.vote_trees import fit_vote

    options = {
        "trees": trees,
        "depth": depth,
        "min_leaf": min_leaf,
        "l2": l2,
        "learning_rate": learning_rate,
        "monotonic": monotonic,
        "structure": structure,
    }
    fit_plan = read_plan(plan, **options)
    command = _command("vote", plan, out, cache, **options)
    record = fit_vote(fit_plan, plan.parent, out, command=command, cache=cache)
    typer.echo(
        f"{record.facts['samples']} samples from {record.facts['scans x labellers']} scans x "
        f"labellers -> {out} (sha256 {record.model_sha256[:12]}), provenance beside it",
        err=True,
    )


@fit_app.command("up-axis")
def up_axis(
    plan: Path = typer.Option(..., "--plan", help=PLAN_HELP),
    out: Path = typer.Option(..., "--out", "-o", help=OUT_HELP),
    cache: Path | None = typer.Option(None, "--cache", help=CACHE_HELP),
) -> None:
    """Fit the up-axis weighing (jointseg/frame/up_model.json) on the plan's rooms, captures."""
    from jointseg.fitting.up_axis import fit_up_axis, read_plan

    command = _command("up-axis", plan, out, cache)
    record = fit_up_axis(read_plan(plan), plan.parent, out, command=command, cache=cache)
    typer.echo(
        f"{record.facts['cases']} cases -> {out} (sha256 {record.model_sha256[:12]}), "
        "provenance beside it",
        err=True,
    )


def register(app: typer.Typer) -> None:
    """Add the `fit` command group to the `jointseg` application."""
    app.add_typer(fit_app, name="fit")
