"""``python -m service`` runs the ``omnisonar`` command line."""

from service.cli import main

raise SystemExit(main())
