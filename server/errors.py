"""Error answers that never fail themselves: a 422 whose body echoes the client's input must stay
valid JSON even when that input holds NaN or infinity (which JSON cannot carry), is huge, or is a
body of bytes that are no UTF-8."""

from __future__ import annotations

import math
from typing import Any

from fastapi import Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

#: Longest string echoed back in an error (characters); longer ones are cut.
MAX_ECHO_CHARS = 200
#: Most items of a list or object echoed back.
MAX_ECHO_ITEMS = 20


def json_safe(value: Any, depth: int = 0) -> Any:
    """``value`` with non-finite floats as strings ("nan", "inf"), bytes as text (undecodable ones
    replaced), strings, lists and objects cut short, nesting below 8 levels as "…": always
    encodable as JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, bytes | bytearray | memoryview):
        value = bytes(value[:MAX_ECHO_CHARS * 4]).decode("utf-8", errors="replace")
    if isinstance(value, str):
        return value if len(value) <= MAX_ECHO_CHARS else value[:MAX_ECHO_CHARS] + "…"
    if depth >= 8 and isinstance(value, (list, tuple, dict)):
        return "…"
    if isinstance(value, (list, tuple)):
        return [json_safe(v, depth + 1) for v in value[:MAX_ECHO_ITEMS]]
    if isinstance(value, dict):
        return {str(k)[:MAX_ECHO_CHARS]: json_safe(v, depth + 1) for k, v in list(value.items())[:MAX_ECHO_ITEMS]}
    return value


async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
    """FastAPI's 422 answer, with the echoed input made JSON-safe (before jsonable_encoder too, which
    fails on bytes that are no UTF-8)."""
    return JSONResponse(status_code=422, content={"detail": json_safe(jsonable_encoder(json_safe(exc.errors())))})
