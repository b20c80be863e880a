"""MkDocs hook: the reference pages' tables, generated from the code at every ``mkdocs build``.

A page asks for a table with a marker line of its own, e.g. ``<!-- reference: server flags -->``:

- ``server flags`` / ``node flags``: every flag of ``python -m server`` / ``python -m node`` from
  their argument parsers (``server.settings.build_parser``, ``node.settings.build_parser``), with its
  ``TESSERA_*`` variable and help text;
- ``http endpoints``: every operation of the coordinator's OpenAPI schema (``server.app.create_app``),
  grouped by tag, with its parameters, request body fields and answers;
- ``other routes``: the routes outside the schema (WebSockets, the viewer page, static files);
- ``messages``: every JSON control message of the sockets, from the catalogue's models
  (``tessera.wire.messages``, ``stream_messages``, ``wall_messages``);
- ``python client``: every public class of ``tessera.client`` with its methods and properties, from
  their signatures and docstrings.

An unknown marker fails the build. ``tests/test_docs.py`` checks the tables against ``--help`` and a
running coordinator's ``/openapi.json``.
"""

from __future__ import annotations

import argparse
import html
import inspect
import json
import re
from collections.abc import Callable, Iterator
from typing import Any

MARKER = re.compile(r"^<!-- reference: (?P<name>[a-z ]+) -->$", re.MULTILINE)
ENV_TAG = re.compile(r"\s*\[env (?P<name>TESSERA_[A-Z0-9_]+)\]")
HTTP_METHODS = ("get", "put", "post", "patch", "delete")
#: The session-scoped routes are mounted twice: for the default session and for any other.
SESSION_PREFIX = "/api/sessions/{session_id}"


def cell(text: str) -> str:
    """``text`` safe inside a Markdown table cell: HTML escaped, pipes and asterisks literal, RST
    literals (````x````) as Markdown code, one line."""
    text = html.escape(" ".join(text.split()), quote=False)
    text = text.replace("|", "\\|").replace("*", "\\*")
    return re.sub(r"``(.+?)``", r"`\1`", text)


# ---- command-line flags ----------------------------------------------------------------------------

def server_parser() -> argparse.ArgumentParser:
    from server.settings import build_parser

    return build_parser()


def node_parser() -> argparse.ArgumentParser:
    from node.settings import build_parser

    # the node's parser takes its defaults from an environment: an empty one gives the built-in ones
    takes_environ = bool(inspect.signature(build_parser).parameters)
    return build_parser({}) if takes_environ else build_parser()  # type: ignore[call-arg]


def flag_actions(parser: argparse.ArgumentParser) -> Iterator[argparse.Action]:
    for action in parser._actions:
        if action.option_strings and not isinstance(action, argparse._HelpAction):
            yield action


def env_variable(action: argparse.Action, every_flag_env: bool) -> str | None:
    """The action's ``TESSERA_*`` variable: the ``[env NAME]`` its help names, else (a parser whose
    every flag has one) ``TESSERA_<DEST>``."""
    found = ENV_TAG.search(action.help or "")
    if found:
        return found["name"]
    return "TESSERA_" + action.dest.upper() if every_flag_env else None


def value_name(action: argparse.Action) -> str:
    if action.nargs == 0:
        return ""
    if action.choices:
        return "{" + ",".join(map(str, action.choices)) + "}"
    if isinstance(action.metavar, str):
        return action.metavar
    return action.dest.upper()


def default_text(value: object) -> str:
    if isinstance(value, tuple) and len(value) == 2 and all(isinstance(v, int) for v in value):
        return f"{value[0]}x{value[1]}"
    if isinstance(value, tuple):
        return ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def flags_table(parser: argparse.ArgumentParser) -> str:
    """One row per flag: the flag (and its aliases) with its value, the variable, what it does."""
    every_flag_env = "TESSERA_<FLAG>" in (parser.description or "") + (parser.epilog or "")
    rows = ["| flag | environment variable | what it does |", "|---|---|---|"]
    for action in flag_actions(parser):
        names = " ".join(f"`{name}`" for name in action.option_strings)
        value = value_name(action)
        flag = f"{names} `{value}`" if value else names
        help_text = ENV_TAG.sub("", action.help or "")
        has_default = action.default not in (None, False, argparse.SUPPRESS)
        if has_default and "default" not in help_text:
            help_text += f" (default {default_text(action.default)})"
        variable = env_variable(action, every_flag_env)
        rows.append(f"| {flag} | {f'`{variable}`' if variable else '—'} | {cell(help_text)} |")
    usage = parser.format_usage().strip()
    return f"```text\n{usage}\n```\n\n{parser.description or ''}\n\n" + "\n".join(rows) + "\n"


# ---- HTTP endpoints -------------------------------------------------------------------------------

def coordinator_app() -> Any:
    from server.app import create_app
    from server.settings import Settings

    return create_app(Settings())


def schema_type(schema: dict[str, Any]) -> str:
    if "$ref" in schema:
        return schema["$ref"].rsplit("/", 1)[-1]
    if "anyOf" in schema:
        return " or ".join(schema_type(option) for option in schema["anyOf"])
    if schema.get("type") == "array":
        return f"array of {schema_type(schema.get('items', {}))}"
    return str(schema.get("type", "any"))


def body_fields(openapi: dict[str, Any], content: dict[str, Any]) -> list[str]:
    """Rows of a request body's fields: name, type, required, what."""
    media, spec = next(iter(content.items()))
    schema = spec.get("schema", {})
    if "$ref" in schema:
        schema = openapi["components"]["schemas"][schema["$ref"].rsplit("/", 1)[-1]]
    required = set(schema.get("required", ()))
    rows = [f"Body ({media}):", "", "| field | type | required | what |", "|---|---|---|---|"]
    for name, field in schema.get("properties", {}).items():
        rows.append(f"| `{name}` | {type_link(field)} | {'yes' if name in required else 'no'} | "
                    f"{cell(field.get('description', ''))} |")
    return rows


def type_link(schema: dict[str, Any]) -> str:
    """The schema's type, a body type linked to its section under Bodies."""
    text = cell(schema_type(schema))
    return re.sub(r"\b([A-Z][A-Za-z]+Body)\b", lambda m: f"[{m[1]}](#{m[1].lower()})", text)


def bodies_markdown(openapi: dict[str, Any]) -> list[str]:
    """A section per request body model of the schema (the validation error models left out)."""
    out = ["## Bodies", ""]
    for name, schema in openapi.get("components", {}).get("schemas", {}).items():
        if "ValidationError" in name:
            continue
        required = set(schema.get("required", ()))
        out += [f"### {name}", "", cell(schema.get("description", "")), "",
                "| field | type | required | what |", "|---|---|---|---|"]
        for field_name, field in schema.get("properties", {}).items():
            what = field.get("description", "")
            if "default" in field and field["default"] is not None:
                what += f" (default {json.dumps(field['default'])})"
            out.append(f"| `{field_name}` | {type_link(field)} | {'yes' if field_name in required else 'no'} | "
                       f"{cell(what)} |")
        out.append("")
    return out


def operation_section(openapi: dict[str, Any], method: str, path: str, also: str | None) -> list[str]:
    operation = openapi["paths"][path][method]
    lines = [f"### `{method.upper()} {path}`", ""]
    if also:
        lines += [f"Also `{method.upper()} {also}` for session `session_id`.", ""]
    lines += [re.sub(r"``(.+?)``", r"`\1`", operation.get("description") or operation.get("summary", "")), ""]
    parameters = [p for p in operation.get("parameters", ()) if p["in"] in ("query", "path")]
    if parameters:
        lines += ["| parameter | in | type | required |", "|---|---|---|---|"]
        lines += [f"| `{p['name']}` | {p['in']} | {cell(schema_type(p.get('schema', {})))} | "
                  f"{'yes' if p.get('required') else 'no'} |" for p in parameters]
        lines.append("")
    if "requestBody" in operation:
        lines += [*body_fields(openapi, operation["requestBody"]["content"]), ""]
    answers = ", ".join(f"{code} {cell(answer.get('description', ''))}"
                        for code, answer in operation["responses"].items())
    lines += [f"Answers: {answers}.", ""]
    return lines


def endpoints_markdown(openapi: dict[str, Any]) -> str:
    """Every operation of ``openapi``, grouped by its first tag; a route mounted both for the default
    session and under ``/api/sessions/{session_id}`` is one section naming both paths."""
    paths = openapi["paths"]
    twins = {path: SESSION_PREFIX + path[len("/api"):] for path in paths
             if path.startswith("/api/") and SESSION_PREFIX + path[len("/api"):] in paths}
    shown = set(twins.values())
    groups: dict[str, list[str]] = {}
    for path, operations in paths.items():
        if path in shown:
            continue
        for method in HTTP_METHODS:
            if method in operations:
                tag = (operations[method].get("tags") or ["other"])[0]
                groups.setdefault(tag, []).extend(operation_section(openapi, method, path, twins.get(path)))
    out: list[str] = []
    for tag, lines in groups.items():
        out += [f"## {tag.capitalize()}", "", *lines]
    return "\n".join(out + bodies_markdown(openapi))


def route_paths(routes: list[Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    """(full path, route) of every route, through included routers."""
    for route in routes:
        if hasattr(route, "original_router"):   # FastAPI's lazily included router
            yield from route_paths(route.original_router.routes, prefix + route.include_context.prefix)
        elif hasattr(route, "path"):
            yield prefix + route.path, route


#: What the routes outside the schema are, where their code says nothing (FastAPI's own, the sockets).
ROUTE_NOTES = {
    "/openapi.json": "this reference as an OpenAPI 3 schema",
    "/docs": "the schema as interactive pages (Swagger UI)",
    "/docs/oauth2-redirect": "part of the interactive pages",
    "/redoc": "the schema as a page (ReDoc)",
    "/": "the viewer page; `?session=ID` a session, `&watch=1` a watch link, `&cell=COL,ROW` a wall's cell, "
         "`?token=…` sets the token cookie",
    "/ws/view": "the viewer socket: frames to the page, camera and input from it (see Messages)",
    "/ws/node": "render nodes (see Messages)",
}


def other_routes_markdown(app: Any) -> str:
    rows = ["| route | what |", "|---|---|"]
    for path, route in route_paths(app.routes):
        kind = type(route).__name__
        doc = (inspect.getdoc(getattr(route, "endpoint", None)) or "").split("\n\n")[0]
        what = cell(doc) or ROUTE_NOTES.get(path, "")
        if "WebSocket" in kind:
            rows.append(f"| `WS {path}` | {what} |")
        elif kind == "Mount":
            rows.append(f"| `GET {path}/…` | the viewer's static files |")
        elif not getattr(route, "include_in_schema", True):
            methods = sorted(set(getattr(route, "methods", ())) - {"HEAD"})
            rows.append(f"| `{' '.join(methods)} {path}` | {what} |")
    return "\n".join(rows) + "\n"


# ---- socket messages ------------------------------------------------------------------------------

def message_directions() -> list[tuple[str, tuple[type, ...]]]:
    """(direction, message classes) in catalogue order; a class in none of the ``FROM_*``/``TO_*``
    tuples is one the coordinator sends to viewers."""
    from tessera.wire import messages, pick_messages, stream_messages, wall_messages

    return [
        ("node → coordinator", (messages.NodeHello, *messages.FROM_NODE, *pick_messages.FROM_NODE_PICKS)),
        ("coordinator → node", (*messages.TO_NODE, *pick_messages.TO_NODE_PICKS)),
        ("viewer → coordinator", (*messages.FROM_VIEWER, *stream_messages.FROM_STREAM_VIEWER,
                                  *wall_messages.FROM_WALL_VIEWER)),
    ]


def all_messages() -> list[type]:
    from tessera.wire import messages, pick_messages, stream_messages, wall_messages  # noqa: F401 (registers them)

    found: list[type] = []
    pending = list(messages.Message.__subclasses__())
    while pending:
        cls = pending.pop(0)
        found.append(cls)
        pending.extend(cls.__subclasses__())
    return found


def annotation_text(annotation: Any) -> str:
    text = getattr(annotation, "__name__", None) if not getattr(annotation, "__args__", None) else None
    text = text or str(annotation)
    text = re.sub(r"\b(?:typing|pydantic\.types|tessera\.[a-z_.]+|annotated_types)\.", "", text)
    return re.sub(r"Annotated\[([^,\]]+)[^\]]*\]", r"\1", text)


def message_rows(classes: tuple[type, ...] | list[type]) -> list[str]:
    rows = ["| `type` | fields | what |", "|---|---|---|"]
    for cls in classes:
        fields = ", ".join(f"`{name}`" for name in cls.model_fields)  # type: ignore[attr-defined]
        doc = inspect.cleandoc(cls.__dict__.get("__doc__") or "").split("\n\n")[0]   # its own, not inherited
        rows.append(f"| `{cls.kind}` | {fields or '—'} | {cell(doc)} |")  # type: ignore[attr-defined]
    return rows


def messages_markdown() -> str:
    out: list[str] = []
    listed: set[type] = set()
    for direction, classes in message_directions():
        out += [f"### {direction}", "", *message_rows(classes), ""]
        listed.update(classes)
    to_viewer = [cls for cls in all_messages() if cls not in listed]
    out += ["### coordinator → viewer", "", *message_rows(to_viewer), ""]
    return "\n".join(out)


# ---- the Python client -----------------------------------------------------------------------------

def prose(doc: str) -> str:
    """A docstring as Markdown: RST literals and cross-references as code, doctest examples as a
    Python block."""
    doc = re.sub(r":(?:meth|class|func|attr|data|mod):`~?([^`]+)`", r"`\1`", doc)
    doc = re.sub(r"``(.+?)``", r"`\1`", doc, flags=re.S)
    return re.sub(r"(?m)((?:^(?:>>>|\.\.\.)(?: .*)?\n?)+)",
                  lambda m: "```python\n" + re.sub(r"(?m)^(?:>>>|\.\.\.) ?", "", m[1]).rstrip("\n") + "\n```\n", doc)


def signature(obj: Any, name: str) -> str:
    """``name(parameters) -> return`` with the annotations as written (no quotes)."""
    try:
        found = inspect.signature(obj)
    except (TypeError, ValueError):
        return name
    parameters = []
    for parameter in found.parameters.values():
        if parameter.name == "self":
            continue
        text = {parameter.VAR_POSITIONAL: "*", parameter.VAR_KEYWORD: "**"}.get(parameter.kind, "") + parameter.name
        if parameter.annotation is not parameter.empty:
            text += f": {annotation_name(parameter.annotation)}"
        if parameter.default is not parameter.empty:
            text += f" = {parameter.default!r}"
        parameters.append(text)
    returns = found.return_annotation
    shown = "" if returns is found.empty or returns in ("None", None) else f" -> {annotation_name(returns)}"
    return f"{name}({', '.join(parameters)}){shown}"


def annotation_name(annotation: Any) -> str:
    return annotation if isinstance(annotation, str) else getattr(annotation, "__name__", str(annotation))


def client_members(cls: type) -> Iterator[tuple[str, Any]]:
    """The public methods and properties ``cls`` itself defines, in source order."""
    for name, member in vars(cls).items():
        if name.startswith("_"):
            continue
        if isinstance(member, (property, classmethod, staticmethod)) or inspect.isfunction(member):
            yield name, member


def client_markdown() -> str:
    import tessera.client as client

    order = ["Tessera", "Session", "TesseraError"]
    names = order + sorted(set(client.__all__) - set(order))
    out: list[str] = []
    for name in names:
        obj = getattr(client, name)
        out += [f"## `{name}`", "", f"```python\n{signature(obj, name)}\n```", "",
                prose(inspect.getdoc(obj) or ""), ""]
        if not inspect.isclass(obj) or not obj.__module__.startswith("tessera.client"):
            continue
        for member_name, member in client_members(obj):
            if isinstance(member, property):
                doc = inspect.getdoc(member) or ""
                kind = "property, settable" if member.fset is not None else "property"
                out += [f"### `{name}.{member_name}` ({kind})", "", prose(doc), ""]
            else:
                function = member.__func__ if isinstance(member, (classmethod, staticmethod)) else member
                out += [f"### `{name}.{member_name}`", "", f"```python\n{signature(function, member_name)}\n```", "",
                        prose(inspect.getdoc(function) or ""), ""]
    return "\n".join(out)


# ---- the hook --------------------------------------------------------------------------------------

def generators() -> dict[str, Callable[[], str]]:
    return {
        "server flags": lambda: flags_table(server_parser()),
        "node flags": lambda: flags_table(node_parser()),
        "http endpoints": lambda: endpoints_markdown(coordinator_app().openapi()),
        "other routes": lambda: other_routes_markdown(coordinator_app()),
        "messages": messages_markdown,
        "python client": client_markdown,
    }


def expand(markdown: str) -> str:
    """``markdown`` with every marker line replaced by its generated table."""
    makers = generators()

    def replace(match: re.Match[str]) -> str:
        name = match["name"]
        if name not in makers:
            raise ValueError(f"unknown reference marker {name!r}; known: {sorted(makers)}")
        return makers[name]()

    return MARKER.sub(replace, markdown)


def on_page_markdown(markdown: str, **_: Any) -> str:
    return expand(markdown) if MARKER.search(markdown) else markdown
