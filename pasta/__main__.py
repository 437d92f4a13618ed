"""Allow ``python -m pasta ...`` as an alias of the ``pasta`` console script."""

from pasta.cli import main

raise SystemExit(main())
