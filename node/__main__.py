"""``python -m node``: a render node (see ``--help``), or ``--render-once OUT.png`` for one frame."""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence

from node.settings import parse_settings


def main(argv: Sequence[str] | None = None) -> int:
    settings = parse_settings(argv)
    if settings.render_once is not None:
        from node.render_once import render_once

        return render_once(settings)
    from node.client import run_node
    from node.gl.environment import EnvironmentError
    from node.gl.image_lighting import keep_environments_in, prefiltered_environment

    keep_environments_in(settings.scene_cache_dir)
    try:
        prefiltered_environment(settings.environment)
    except EnvironmentError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format=f"%(asctime)s node {settings.name} %(levelname)s %(message)s")
    return run_node(settings)


if __name__ == "__main__":
    sys.exit(main())
