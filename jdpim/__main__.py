"""``python -m jdpim``: the command line (``run`` is the default: the main job)."""

from jdpim.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
