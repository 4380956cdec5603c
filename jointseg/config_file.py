"""Parameter files (JSON) validated against a pydantic model once, where they are read: the
command line's --params and --config, and the fit plans of `jointseg fit`. An error names the
file and the field, as one line a user can act on."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TypeVar

from pydantic import BaseModel, ValidationError

from jointseg.exceptions import ConfigError

M = TypeVar("M", bound=BaseModel)


def load_params_file(
    path: Path | None, model: type[M], extra: dict[str, object] | None = None
) -> M:
    """Validate a JSON parameter file against a pydantic ``model``; errors name the field.
    ``extra`` top-level values (command-line options) replace the file's."""
    data: object = {}
    if path is not None:
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError as exc:
            raise ConfigError(f"{path}: file not found") from exc
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from exc
    if extra and isinstance(data, dict):
        data = {**data, **extra}
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "(top level)"
        source = f"{path}: " if path is not None else ""
        raise ConfigError(
            f"{source}parameter {where!r}: {first['msg']} (got {first.get('input')!r})"
        ) from exc
