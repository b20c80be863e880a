"""Open a session on a Tessera coordinator, turn around the scene and save a picture per step.

    python examples/orbit_and_save.py [--url http://127.0.0.1:8000] [--scene builtin:cluster] [--out shots]

The coordinator: ``python -m server --local-nodes 2`` (add ``--token`` and pass ``--token`` here, or
set TESSERA_URL / TESSERA_TOKEN).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from tessera.client import Tessera


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--url", help="the coordinator (default $TESSERA_URL or http://127.0.0.1:8000)")
    parser.add_argument("--token", help="its token, if it has one (default $TESSERA_TOKEN)")
    parser.add_argument("--scene", default="builtin:cluster", help="a scene of the library (default builtin:cluster)")
    parser.add_argument("--steps", type=int, default=4, help="pictures around the scene (default 4)")
    parser.add_argument("--out", type=Path, default=Path("shots"), help="folder for the pictures (default shots/)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with Tessera(args.url, token=args.token) as tessera, \
            tessera.open_session(args.scene, size=(640, 360)) as session:
        session.fit()
        for step in range(args.steps):
            if step:
                session.orbit(360 / args.steps)
            path = session.save(args.out / f"{step:02d}.png")   # the lossless still, once it converged
            print(f"{path}: camera eye {[round(v, 3) for v in session.camera.eye]}")


if __name__ == "__main__":
    main()
