"""MkDocs hook: the REST API page rendered from the job service's own OpenAPI schema.

The schema comes from ``server.api.app.create_app()`` at build time (no database is opened:
the app's lifespan never runs), so the page cannot drift from the routes; the schema itself is
written beside the page as ``openapi.json`` for tools that read it.
"""

from __future__ import annotations

import json
import re
from typing import Any

MARKER = "<!-- openapi -->"
METHODS = ("get", "post", "put", "patch", "delete")


#: this build's schema, made once in ``on_files`` (which runs before any page) and reused by
#: the page; rebuilt on every build, so ``mkdocs serve`` follows changed routes
_built: dict[str, Any] = {}


def _schema() -> dict[str, Any]:
    from server.api.app import create_app

    return create_app().openapi()


def _text(value: str | None) -> str:
    """Docstring text (reST literals) as Markdown on one line, pipes escaped for tables."""
    text = re.sub(r"``([^`]+)``", r"`\1`", value or "")
    return " ".join(text.split()).replace("|", "\\|")


def _type(schema: dict[str, Any]) -> str:
    """A short type for a JSON schema: ``JobView``, ``array of ObjectRecord``, ``"a" | "b"``."""
    if "$ref" in schema:
        name = schema["$ref"].rsplit("/", 1)[-1]
        return f"[{name}](#{name.lower()})"
    if "anyOf" in schema:
        return " or ".join(_type(s) for s in schema["anyOf"])
    if "enum" in schema:
        return " \\| ".join(f"`{json.dumps(v)}`" for v in schema["enum"])
    kind = schema.get("type", "any")
    if kind == "array":
        return f"array of {_type(schema.get('items', {}))}"
    if kind == "object" and "additionalProperties" in schema:
        extra = schema["additionalProperties"]
        return f"object of {_type(extra)}" if isinstance(extra, dict) else "object"
    if "format" in schema:
        return f"{kind} ({schema['format']})"
    return str(kind)


def _limits(schema: dict[str, Any]) -> str:
    words = {"minimum": "≥", "maximum": "≤", "exclusiveMinimum": ">", "exclusiveMaximum": "<"}
    parts = [f"{sign} {schema[key]}" for key, sign in words.items() if key in schema]
    if "default" in schema:
        parts.append(f"default `{json.dumps(schema['default'])}`")
    return ", ".join(parts)


def _described(text: str | None, schema: dict[str, Any]) -> str:
    """A field's description with its bounds and default after it."""
    desc, limits = _text(text), _limits(schema)
    return f"{desc} ({limits})" if limits and desc else desc or limits


def _operation(path: str, method: str, op: dict[str, Any]) -> list[str]:
    lines = [f"### `{method.upper()} {path}`", "", _text(op.get("description") or op["summary"])]
    if op.get("security"):
        lines += ["", "Needs the API key (`Authorization: Bearer KEY`) when the service has any."]
    params = op.get("parameters", [])
    if params:
        lines += ["", "| parameter | in | type | required | description |", "|---|---|---|---|---|"]
        for p in params:
            schema = p.get("schema", {})
            desc = _described(p.get("description") or schema.get("description"), schema)
            lines.append(
                f"| `{p['name']}` | {p['in']} | {_type(schema)} | "
                f"{'yes' if p.get('required') else 'no'} | {desc} |"
            )
    body = op.get("requestBody")
    if body:
        for media, content in body.get("content", {}).items():
            schema = content.get("schema", {})
            lines += ["", f"Request body (`{media}`):"]
            props = schema.get("properties")
            if props:
                lines += ["", "| field | type | required | description |", "|---|---|---|---|"]
                required = set(schema.get("required", []))
                for name, prop in props.items():
                    lines.append(
                        f"| `{name}` | {_type(prop)} | {'yes' if name in required else 'no'} | "
                        f"{_text(prop.get('description'))} |"
                    )
            else:
                lines.append(f" {_type(schema)}")
    lines += ["", "| status | meaning | body |", "|---|---|---|"]
    for code, response in op.get("responses", {}).items():
        contents = response.get("content", {})
        kinds = [
            f"{_type(c['schema'])} (`{media}`)" if c.get("schema") else f"`{media}`"
            for media, c in contents.items()
        ]
        lines.append(f"| {code} | {_text(response.get('description'))} | {', '.join(kinds)} |")
    return lines + [""]


def _component(name: str, schema: dict[str, Any]) -> list[str]:
    lines = [f"### {name}", "", _text(schema.get("description"))]
    props = schema.get("properties", {})
    if props:
        required = set(schema.get("required", []))
        lines += ["", "| field | type | required | description |", "|---|---|---|---|"]
        for field, prop in props.items():
            lines.append(
                f"| `{field}` | {_type(prop)} | {'yes' if field in required else 'no'} | "
                f"{_described(prop.get('description'), prop)} |"
            )
    return lines + [""]


def render(schema: dict[str, Any]) -> str:
    """The schema as Markdown: every operation, then every component schema."""
    info = schema["info"]
    lines = [f"{_text(info.get('summary'))} (OpenAPI {schema['openapi']}, API version "
             f"{info['version']}.) The machine-readable schema: [openapi.json](openapi.json);"
             " a running service also serves it at `/openapi.json` and an interactive page at"
             " `/docs`.", "", "## Operations", ""]  # fmt: skip
    for path, item in schema["paths"].items():
        for method in METHODS:
            if method in item:
                lines += _operation(path, method, item[method])
    lines += ["## Schemas", ""]
    for name, component in sorted(schema.get("components", {}).get("schemas", {}).items()):
        lines += _component(name, component)
    return "\n".join(lines)


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    if MARKER not in markdown:
        return markdown
    return markdown.replace(MARKER, render(_built["schema"]))


def on_files(files: Any, config: Any) -> Any:
    from mkdocs.structure.files import File

    _built["schema"] = _schema()
    content = json.dumps(_built["schema"], indent=2)
    files.append(File.generated(config, "reference/openapi.json", content=content))
    return files
