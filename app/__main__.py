"""`python -m app` behaves like the `orientation-lab` console script."""

from app.cli import main

raise SystemExit(main())
