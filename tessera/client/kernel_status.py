"""Quiet comms: the kernel tells the page no ``busy`` for a message to a notebook view's comm.

Every message a page sends to the kernel is a shell request: ipykernel publishes the status
``busy`` before handling it and ``idle`` after, and JupyterLab shows each change (the kernel's
status in the toolbar and the status bar, the tab's icon and title): a style, layout and paint of
the whole page twice a message. The comm view sends one message a frame, so that work took the
page's main thread and the CPU the render nodes draw with. For the comms marked here the kernel
publishes ``idle`` only: the page's status never leaves idle (no change to show), and JupyterLab
still ends (and disposes of) the message's future on the ``idle``. Every other message keeps
both. Installed on the running ipykernel's instance; elsewhere (no kernel, another kernel) nothing
changes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

#: Comm ids whose messages the kernel answers without ``busy``.
QUIET: set[str] = set()
#: Marks the kernel's ``_publish_status`` once wrapped.
WRAPPED = "_tessera_quiet_comms"


def is_quiet(message: Any, status: str, channel: str) -> bool:
    """Whether ``status`` on ``channel`` for the request ``message`` (a deserialized message dict)
    is a ``busy`` for a comm message to a quiet comm."""
    if status != "busy" or channel != "shell" or not isinstance(message, dict):
        return False
    header, content = message.get("header"), message.get("content")
    return (isinstance(header, dict) and header.get("msg_type") == "comm_msg" and isinstance(content, dict)
            and content.get("comm_id") in QUIET)


def _running_kernel() -> Any:
    """The ipykernel instance this process runs, or None."""
    try:
        from ipykernel.kernelbase import Kernel
    except ImportError:
        return None
    return Kernel.instance() if Kernel.initialized() else None


def quiet(comm_id: str) -> bool:
    """Answer ``comm_id``'s messages without ``busy``; False where no ipykernel runs here (or one
    whose status publishing is not the one known), which changes nothing."""
    kernel = _running_kernel()
    publish = getattr(kernel, "_publish_status", None)
    if kernel is None or not callable(publish) or not callable(getattr(kernel, "get_parent", None)):
        return False
    if not getattr(publish, WRAPPED, False):
        kernel._publish_status = _quiet_publisher(kernel, publish)
    QUIET.add(comm_id)
    return True


def unquiet(comm_id: str) -> None:
    """``comm_id``'s messages get ``busy`` again (its view closed)."""
    QUIET.discard(comm_id)


def _quiet_publisher(kernel: Any, publish: Callable[..., Any]) -> Callable[..., Any]:
    def publish_status(status: str, channel: str, parent: Any = None) -> Any:
        if QUIET and status == "busy":
            try:
                request = parent or kernel.get_parent(channel)
            except Exception:   # an ipykernel that keeps its parents otherwise: publish as it would
                request = None
            if is_quiet(request, status, channel):
                return None
        return publish(status, channel, parent)

    setattr(publish_status, WRAPPED, True)
    return publish_status
