"""``python -m pointrig`` runs the CLI."""

from .cli import main

raise SystemExit(main())
