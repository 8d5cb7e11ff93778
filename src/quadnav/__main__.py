"""``python -m quadnav``."""

from quadnav.cli.main import main

main()
