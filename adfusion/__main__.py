"""``python -m adfusion`` runs the command line (``adfusion --help``)."""

from adfusion.app.cli import main

raise SystemExit(main())
