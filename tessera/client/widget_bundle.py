"""The notebook view's front end as one ES module: ``widget.js`` and the viewer's own modules it
imports (``web/``: served by the coordinator as ``server/viewer``), each in a function scope of its
own with its imports bound to the exporting module's names, so no JavaScript is written twice."""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

#: The widget's entry module, beside this file.
WIDGET_JS = Path(__file__).with_name("widget.js")
#: ``import { a, b as c } from "./name.js";`` (the form the viewer's modules use).
IMPORT = re.compile(r'^import\s*\{([^}]*)\}\s*from\s*"\./([\w-]+)\.js";\s*$', re.M)
#: ``export function|class|const|let NAME`` and ``export default``.
EXPORT = re.compile(r"^export\s+(?:async\s+)?(?:function\*?|class|const|let)\s+([A-Za-z_$][\w$]*)", re.M)


def viewer_dir() -> Path:
    """The viewer's modules: ``web/`` of a checkout, else the installed ``server/viewer`` (found
    beside the ``tessera`` package, not imported)."""
    root = Path(__file__).resolve().parents[2]
    for candidate in (root / "web", root / "server" / "viewer"):
        if (candidate / "protocol.js").is_file():
            return candidate
    raise FileNotFoundError(f"the viewer's modules are in neither {root / 'web'} nor {root / 'server' / 'viewer'}")


def _bindings(names: str) -> str:
    """``a, b as c`` → ``a, b: c`` (a destructuring pattern)."""
    parts = [part.strip() for part in names.split(",") if part.strip()]
    return ", ".join(part.replace(" as ", ": ") for part in parts)


def _module_scope(name: str, source: str) -> tuple[str, list[str]]:
    """``source``'s body with imports bound from their modules' scopes, and the modules it imports."""
    needs = [match.group(2) for match in IMPORT.finditer(source)]
    body = IMPORT.sub(lambda m: f"const {{ {_bindings(m.group(1))} }} = module_{m.group(2)};", source)
    exports = EXPORT.findall(body)
    body = re.sub(r"^export\s+(?=(?:async\s+)?(?:function|class|const|let)\b)", "", body, flags=re.M)
    return f"const module_{name} = (() => {{\n{body}\nreturn {{ {', '.join(exports)} }};\n}})();\n", needs


@cache
def widget_module() -> str:
    """The widget's ES module: the viewer modules ``widget.js`` needs (dependencies first), then
    ``widget.js`` itself with its ``export default``."""
    web = viewer_dir()
    scopes: dict[str, str] = {}

    def add(name: str) -> None:
        if name in scopes:
            return
        scope, needs = _module_scope(name, (web / f"{name}.js").read_text())
        for need in needs:
            add(need)
        scopes[name] = scope

    entry = WIDGET_JS.read_text()
    for need in IMPORT.findall(entry):
        add(need[1])
    body = IMPORT.sub(lambda m: f"const {{ {_bindings(m.group(1))} }} = module_{m.group(2)};", entry)
    return "".join(scopes.values()) + body
