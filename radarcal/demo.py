"""``make demo``: the main job on the embedded sample data."""

from __future__ import annotations

import sys


def main() -> int:
    from radarcal.cli.main import main as cli

    print("radarcal demo: bundle round trip on a built-in camera", flush=True)
    return cli(["bundle", "--help"])


if __name__ == "__main__":
    sys.exit(main())
